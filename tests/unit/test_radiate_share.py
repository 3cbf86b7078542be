"""RADIATE-like fog: return share and range profile, and the visibility fit by each."""

from __future__ import annotations

import numpy as np
import pytest

from lads.calibration.radiate_share import (
    NEAR_GROUND_ELEVATION_DEG,
    ReturnProfile,
    band_channels,
    band_profile,
    fit_visibility,
    near_ground_share,
    profile_distance,
    returns_profile,
    simulated_curves,
)
from lads.errors import ConfigError
from lads.sensors.profile import load_profile


def _points_at(ranges_m: list[float]) -> np.ndarray:
    return np.array([[r, 0.0, 0.0] for r in ranges_m], dtype=np.float32)


def test_profile_counts_returns_beyond_the_body_per_fired_beam() -> None:
    xyz = _points_at([0.5, 1.0, 3.0, 7.0, 15.0, 30.0, 50.0])
    p = returns_profile(xyz, firings=10)
    assert p.share == pytest.approx(0.5)  # the two within BODY_M are the vehicle
    assert p.per_bin == pytest.approx((0.2, 0.2, 0.2, 0.2, 0.2))
    assert returns_profile(_points_at([0.2]), firings=4).per_bin == (0.0,) * 5
    with pytest.raises(ConfigError, match="firings"):
        returns_profile(xyz, firings=0)


def test_profile_distance_is_total_variation() -> None:
    a = ReturnProfile(0.3, (1.0, 0.0, 0.0, 0.0, 0.0))
    b = ReturnProfile(0.3, (0.0, 0.5, 0.5, 0.0, 0.0))
    assert profile_distance(a, a) == 0.0
    assert profile_distance(a, b) == pytest.approx(1.0)


def test_fit_picks_the_closest_visibility_by_each_measure() -> None:
    curve = {
        10.0: ReturnProfile(0.30, (0.9, 0.1, 0.0, 0.0, 0.0)),
        100.0: ReturnProfile(0.60, (0.1, 0.5, 0.4, 0.0, 0.0)),
    }
    real = ReturnProfile(0.28, (0.0, 0.6, 0.4, 0.0, 0.0))
    assert fit_visibility(real, curve, "share") == 10.0
    assert fit_visibility(real, curve, "profile") == 100.0
    with pytest.raises(ConfigError, match="expected one of"):
        fit_visibility(real, curve, "both")
    with pytest.raises(ConfigError):
        fit_visibility(real, {}, "share")


def test_dense_fog_removes_far_returns_and_curves_repeat() -> None:
    # A grey wall 50 m away on every beam of a fan.
    az = np.radians(np.linspace(0, 90, 400))
    xyz = np.stack([50 * np.cos(az), 50 * np.sin(az), np.zeros_like(az)], axis=1)
    frame = (xyz.astype(np.float32), np.full(az.size, 40.0, dtype=np.float32))
    sensor = load_profile("hdl32e")
    curves = simulated_curves([frame], 400, sensor, ("all", "upper"), (6.0, 600.0))
    curve = curves["all"]
    assert curve[600.0].per_bin[-1] > 0.5  # light haze: the wall is still seen
    assert curve[6.0].per_bin[-1] == 0.0  # dense fog: nothing beyond 40 m
    # the fan lies at 0 deg, in the upper band: the same returns out of fewer firings
    upper = curves["upper"][600.0]
    assert upper.per_bin == curve[600.0].per_bin and upper.share > curve[600.0].share
    assert simulated_curves([frame], 400, sensor, ("all", "upper"), (6.0, 600.0)) == curves


def test_near_ground_share_counts_only_the_near_ground_channels():
    sensor = load_profile("hdl32e")
    elevation = np.radians(np.asarray(sensor.elevation_deg))
    lo, hi = NEAR_GROUND_ELEVATION_DEG
    channels = np.flatnonzero((np.degrees(elevation) > lo) & (np.degrees(elevation) < hi))
    assert np.array_equal(band_channels(sensor, "near_ground"), channels)
    az = np.radians(np.arange(100) * 3.6)

    def ring(k: int, range_m: float, count: int) -> np.ndarray:
        a = az[:count]
        return range_m * np.stack(
            [
                np.cos(elevation[k]) * np.cos(a),
                np.cos(elevation[k]) * np.sin(a),
                np.full(count, np.sin(elevation[k])),
            ],
            axis=1,
        )

    # Half the firings of every near-ground channel return from the road; the body (1 m) and
    # the horizon channel do not count.
    parts = [ring(k, 7.0, 50) for k in channels] + [ring(channels[0], 1.0, 50), ring(23, 30.0, 100)]
    assert near_ground_share(np.vstack(parts), 100, sensor) == pytest.approx(0.5)


def test_channel_bands_split_the_channels_and_count_their_own_firings():
    sensor = load_profile("hdl32e")
    bands = [band_channels(sensor, b) for b in ("steep", "near_ground", "upper")]
    assert np.array_equal(np.sort(np.concatenate(bands)), band_channels(sensor, "all"))
    elevation = np.radians(np.asarray(sensor.elevation_deg))
    # one return 20 m out on every upper channel, one on the steepest channel
    ks = list(band_channels(sensor, "upper")) + [0]
    xyz = np.array([[20 * np.cos(elevation[k]), 0.0, 20 * np.sin(elevation[k])] for k in ks])
    upper = band_profile(xyz, 10, sensor, "upper")
    assert upper.share == pytest.approx(1 / 10)
    assert band_profile(xyz, 10, sensor, "steep").share == pytest.approx(1 / (10 * bands[0].size))
    assert band_profile(xyz, 10, sensor, "all").share == pytest.approx(len(ks) / (10 * 32))
    with pytest.raises(ConfigError, match="channel band"):
        band_channels(sensor, "sky")
