"""The HDL-32E's detection limit measured on real nuScenes frames: two scenes agree, and the
shipped profile holds the fit."""

from __future__ import annotations

from pathlib import Path

from lads.sensors.detection_fit import fit_detection_limit
from lads.sensors.profile import load_profile


def test_two_real_nuscenes_scenes_give_the_same_limit(shared_data: Path) -> None:
    from benchmarks.detection_limit import nuscenes_scenes

    fits = [fit_detection_limit(r, i, load_profile("hdl32e")) for r, i in nuscenes_scenes()]
    powers = [f.limit_power for f in fits]
    assert max(powers) / min(powers) < 1.5
    assert all(0.2 < f.spread_ln < 0.6 for f in fits)
    profile = load_profile("hdl32e").detection
    assert min(powers) / 1.5 < profile.power < max(powers) * 1.5  # the profile holds the fit
