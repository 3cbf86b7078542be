"""Every real scan passes the check that it is a scan of its own sensor; a real scan judged
against a clearly different sensor is refused."""

from __future__ import annotations

import numpy as np
import pytest

from lads.errors import InvalidPointsError
from lads.sensors.conformity import check_scan_of
from lads.sensors.profile import load_profile
from tests.real_trees import real_scan_files
from tests.trees import SHARED_DATA


def _scan(rel: str) -> tuple[np.ndarray, np.ndarray | None, str]:
    """(xyz, ring or None, sensor profile name) of a real scan file."""
    path = SHARED_DATA / rel
    if rel.endswith(".csv"):
        rows = np.loadtxt(path, delimiter=",", ndmin=2)
        return rows[:, :3], rows[:, 4], "hdl32e"
    if rel.endswith((".pcd.bin", "points.bin")):
        rows = np.fromfile(path, dtype="<f4").reshape(-1, 5)
        return rows[:, :3], rows[:, 4], "hdl32e"
    rows = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    sensor = "wads64" if rel.startswith("wads") else "hdl32e" if "nuscenes" in rel else "hdl64e"
    return rows[:, :3], None, sensor


def test_every_real_scan_is_a_scan_of_its_own_sensor(shared_data):
    files = real_scan_files()
    assert len(files) == 111
    for rel in files:
        xyz, ring, sensor = _scan(rel)
        profile = load_profile(sensor)
        check_scan_of(xyz, profile, where=rel)
        if ring is not None:
            check_scan_of(xyz, profile, ring=ring, where=rel)


def test_a_real_nuscenes_keyframe_is_not_an_hdl64e_scan(shared_data):
    xyz, ring, _ = _scan("nuscenes-scene0001/data0/points.bin")
    hdl64 = load_profile("hdl64e")
    with pytest.raises(InvalidPointsError, match="field of view"):
        check_scan_of(xyz, hdl64)
    with pytest.raises(InvalidPointsError, match="median elevation"):
        check_scan_of(xyz, hdl64, ring=ring)
