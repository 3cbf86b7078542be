"""Per-point modalities on real frames (docs/physics.md §10.1, §10.3)."""

from __future__ import annotations

import numpy as np

from lads.physics.modalities import IncidenceSource, channels, compute_modalities
from lads.sensors.profile import load_profile
from tests.trees import NUSC_FULL_SAMPLE

HDL64 = load_profile("hdl64e")
NUSC_FULL_SAMPLE_PATH = f"nuscenes/{NUSC_FULL_SAMPLE}"


def test_kitti_frame_gets_a_plausible_cos_for_every_point(shared_data):
    KITTI = shared_data / "semantickitti" / "sequences" / "00"
    points = np.fromfile(KITTI / "velodyne" / "000000.bin", np.float32).reshape(-1, 4)
    labels = np.fromfile(KITTI / "labels" / "000000.label", np.uint32)
    mods = compute_modalities(points[:, :3], labels, "semantickitti", HDL64)
    cos = mods.cos_incidence
    assert cos.shape == (124_668,) and np.all(np.isfinite(cos)) and np.all((cos >= 0) & (cos <= 1))
    # docs/physics.md §10.3 quotes ~0.35 for ReaLiTy's 64 x 1024 projection; this one gives ~0.40.
    assert 0.3 < cos.mean() < 0.5
    assert np.mean(mods.incidence_source == IncidenceSource.IMAGE) > 0.85
    assert np.all(np.isfinite(mods.physics_intensity))


def test_nuscenes_channels_equal_the_ring_column(shared_data):
    points = np.fromfile(shared_data / NUSC_FULL_SAMPLE_PATH, np.float32).reshape(-1, 5)
    profile = load_profile("hdl32e")
    ring = points[:, 4]
    np.testing.assert_array_equal(channels(points[:, :3], profile, ring=ring), ring)
    # Ego-body returns at 1e-5 m stay in the frame, with finite (clamped) physics intensity.
    labels = np.zeros(len(points), np.uint8)
    mods = compute_modalities(points[:, :3], labels, "nuscenes", profile, ring=ring)
    assert np.all(np.isfinite(mods.physics_intensity)) and len(mods.range_m) == 34_688
