"""Sensor profiles against real scans: the nuScenes ring column and the HDL-32E table."""

from __future__ import annotations

import numpy as np

from lads.sensors.profile import load_profile


def test_nuscenes_ring_column_agrees_with_the_elevation_table(shared_data):
    scan = next((shared_data / "nuscenes" / "samples" / "LIDAR_TOP").glob("*.pcd.bin"))
    points = np.fromfile(scan, dtype=np.float32).reshape(-1, 5)
    far = np.linalg.norm(points[:, :3], axis=1) > 5.0
    agree = load_profile("hdl32e").channel_of(points[far, :3]) == points[far, 4].astype(int)
    assert agree.mean() > 0.9
