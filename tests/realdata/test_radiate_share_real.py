"""RADIATE's real foggy frames as lads.calibration.radiate_share counts them."""

from __future__ import annotations

from pathlib import Path

import pytest

from lads.calibration import radiate, radiate_share
from lads.calibration.radiate_share import BODY_M


def test_radiate_frames_return_on_a_fifth_to_two_fifths_of_clean_beams(shared_data: Path) -> None:
    folder = shared_data / "radiate" / "tiny_foggy" / "velo_lidar"
    for path in sorted(folder.glob("*.csv")):
        p = radiate_share.radiate_profile(radiate.load_frame(path))
        assert 0.2 <= p.share <= 0.4
        assert sum(p.per_bin) == pytest.approx(1.0)
        assert p.per_bin[-1] < 0.01  # nothing of note beyond 40 m in this fog
    assert BODY_M < radiate.NEAR_M
