"""The shipped snow knobs reproduce real WADS falling snow better than LISA's settings.

Real data: ../shared/data/wads/sequences/36 (3 labelled frames) and the RADIATE fog sample.
The expensive fit lives in benchmarks/wads_snow.py; these tests evaluate fixed knobs only.
"""

from __future__ import annotations

import numpy as np
import pytest

from lads.calibration import radiate as R
from lads.calibration import wads as W

pytestmark = pytest.mark.realdata

FRAMES = ("042223", "042224", "042225")


@pytest.fixture(scope="module")
def scenes(shared_data):
    seq = shared_data / "wads" / "sequences" / "36"
    if not seq.is_dir():
        pytest.skip(f"{seq} not found")
    return [W.scene_from_frame(f) for f in W.load_sequence(seq, FRAMES)]


def test_real_wads_statistics_match_the_documented_ones(scenes):
    # docs/physics.md §5.3: 110 is 4.98-5.27 % of rows, p5/p50/p95 4.05/6.58/10.98 m pooled.
    for s in scenes:
        assert 0.045 < s.real["snow_row_fraction"] < 0.056
        p5, p50, p95 = s.real["snow_range_pct_rows"]
        assert 3.8 < p5 < 4.3 and 6.2 < p50 < 6.9 and 10.5 < p95 < 11.5
        assert s.real["snow_intensity_zero_share"] > 0.97
        assert 0.40 < s.real["duplicate_row_share"] < 0.43


def test_fitted_knobs_beat_lisa_settings_on_range(scenes):
    ours = W.evaluate(scenes, W.FITTED_SNOW_KNOBS.params(), mode="strongest", seeds=(0,))
    lisa = W.evaluate(scenes, W.LISA_SNOW, mode="strongest", seeds=(0,))
    assert ours["ks_range"] < 0.08
    assert ours["ks_range"] < lisa["ks_range"] / 5
    assert 1 / 1.5 < ours["fraction_ratio"] < 1.5
    assert abs(ours["range_pct_sim"][1] - ours["range_pct_real"][1]) < 0.5


def test_dual_return_knobs_reproduce_wads(scenes):
    ours = W.evaluate(scenes, W.FITTED_DUAL_KNOBS.params(), mode="dual", seeds=(0,))
    lisa = W.evaluate(scenes, W.LISA_SNOW, mode="dual", seeds=(0,))
    assert ours["ks_range"] < 0.08 < lisa["ks_range"]
    assert 1 / 1.5 < ours["fraction_ratio"] < 1.5


def test_snow_defaults_carry_the_fitted_knobs():
    """Fails until SNOW_DEFAULTS in lads/physics/weather.py take W.FITTED_SNOW_KNOBS."""
    from lads.physics.weather import SNOW_DEFAULTS

    k = W.FITTED_SNOW_KNOBS
    assert SNOW_DEFAULTS.particle_reflectivity == pytest.approx(k.particle_reflectivity)
    assert SNOW_DEFAULTS.beam_divergence_mrad == pytest.approx(k.beam_divergence_mrad)
    assert SNOW_DEFAULTS.min_range_m == pytest.approx(k.min_range_m)
    assert SNOW_DEFAULTS.overlap_full_m == pytest.approx(k.overlap_full_m)
    assert SNOW_DEFAULTS.detection_threshold is None


def test_radiate_near_returns_are_platform_not_fog(shared_data):
    path = shared_data / "radiate" / "tiny_foggy" / "velo_lidar" / "000018.csv"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    stats = R.frame_stats(R.load_frame(path))
    assert stats["near_returns_azimuth_-180_0"] > 10 * stats["near_returns_azimuth_0_180"]
    assert stats["near_share_of_beams_clean_half"] < 0.02
    assert np.isfinite(stats["max_range_m"])
