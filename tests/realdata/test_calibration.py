"""The shipped snow knobs reproduce real WADS falling snow better than LISA's settings.

Real data: ../shared/data/wads{,-more}/sequences/36 (labelled frames) and the RADIATE fog sample.
The expensive fit lives in benchmarks/wads_snow.py; these tests evaluate fixed knobs only.
"""

from __future__ import annotations

import numpy as np
import pytest

from lads.calibration import radiate as R
from lads.calibration import wads as W

pytestmark = pytest.mark.realdata

# Held-out WADS frames: never used by the fit (benchmarks/wads_snow.py fits on others).
HELD_OUT = ("042230", "042231", "042232", "042233")
ORIGINAL = ("042223", "042224", "042225")


def _scenes(shared_data, names):
    found = []
    for name in names:
        for root in ("wads", "wads-more"):
            seq = shared_data / root / "sequences" / "36"
            if (seq / "velodyne" / f"{name}.bin").is_file():
                found.extend(W.scene_from_frame(f) for f in W.load_sequence(seq, (name,)))
                break
        else:
            pytest.skip(f"WADS frame {name} not found under {shared_data}")
    return found


@pytest.fixture(scope="module")
def scenes(shared_data):
    return _scenes(shared_data, ORIGINAL)


@pytest.fixture(scope="module")
def held_out(shared_data):
    return _scenes(shared_data, HELD_OUT)


def test_real_wads_statistics_match_the_documented_ones(scenes):
    # docs/physics.md §5.3: 110 is 4.98-5.27 % of rows, p5/p50/p95 4.05/6.58/10.98 m pooled.
    for s in scenes:
        assert 0.045 < s.real["snow_row_fraction"] < 0.056
        p5, p50, p95 = s.real["snow_range_pct_rows"]
        assert 3.8 < p5 < 4.3 and 6.2 < p50 < 6.9 and 10.5 < p95 < 11.5
        assert s.real["snow_intensity_zero_share"] > 0.97
        assert 0.40 < s.real["duplicate_row_share"] < 0.43


def test_fitted_knobs_reproduce_held_out_wads_snow_far_better_than_lisa(held_out):
    """The dual-return mode (WADS records dual returns) on frames the fit never saw."""
    knobs = W.FITTED_SNOW_KNOBS
    ours = W.evaluate(held_out, knobs.params(), mode="dual", seeds=(0,), sensor=knobs.sensor())
    lisa = W.evaluate(held_out, W.LISA_SNOW, mode="dual", seeds=(0,), sensor=knobs.sensor())
    assert ours["ks_range"] < 0.08 < lisa["ks_range"]
    assert ours["ks_range"] < lisa["ks_range"] / 5
    assert 1 / 1.5 < ours["fraction_ratio"] < 1.5
    assert abs(ours["range_pct_sim"][1] - ours["range_pct_real"][1]) < 0.5


def test_a_single_return_sensor_records_fewer_flakes_than_the_dual_return_recording(held_out):
    """Strongest return keeps only flakes that beat their target: a subset of dual's."""
    knobs = W.FITTED_SNOW_KNOBS
    kw = {"seeds": (0,), "sensor": knobs.sensor()}
    single = W.evaluate(held_out, knobs.params(), mode="strongest", **kw)
    dual = W.evaluate(held_out, knobs.params(), mode="dual", **kw)
    assert 0 < single["fraction_sim"] < dual["fraction_sim"]


def test_snow_defaults_and_the_wads_profile_carry_the_fitted_knobs():
    """SNOW_DEFAULTS hold the fitted flake optics and wads64.yaml the fitted detection limit."""
    from lads.physics.weather import SNOW_DEFAULTS
    from lads.sensors.profile import load_profile

    k = W.FITTED_SNOW_KNOBS
    assert SNOW_DEFAULTS.particle_reflectivity == pytest.approx(k.particle_reflectivity)
    assert SNOW_DEFAULTS.beam_divergence_mrad == pytest.approx(k.beam_divergence_mrad)
    assert SNOW_DEFAULTS.min_range_m == pytest.approx(k.min_range_m)
    assert SNOW_DEFAULTS.overlap_full_m == pytest.approx(k.overlap_full_m)
    assert SNOW_DEFAULTS.detection_threshold == "sensor"
    assert load_profile(W.SENSOR).detection.power == pytest.approx(k.detection_threshold, rel=0.01)


def test_radiate_near_returns_are_platform_not_fog(shared_data):
    path = shared_data / "radiate" / "tiny_foggy" / "velo_lidar" / "000018.csv"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    stats = R.frame_stats(R.load_frame(path))
    assert stats["near_returns_azimuth_-180_0"] > 10 * stats["near_returns_azimuth_0_180"]
    assert stats["near_share_of_beams_clean_half"] < 0.02
    assert np.isfinite(stats["max_range_m"])
