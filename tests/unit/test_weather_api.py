"""The public weather API (lads.physics.weather): input checks, output contract, encodings."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lads.errors import ConfigError, IntensityEncodingError, InvalidPointsError, LadsError
from lads.physics.beams import auto_threshold, prepare_beams
from lads.physics.result import Outcome
from lads.physics.weather import FOG_DEFAULTS, RAIN_DEFAULTS, fog, rain, snow, with_overrides
from lads.sensors.profile import load_profile
from tests.conftest import street_frame

CALLS = {
    "rain": lambda x, i, g, **kw: rain(x, i, rate_mm_h=25.0, rng=g, **kw),
    "snow": lambda x, i, g, **kw: snow(x, i, rate_mm_h=5.0, rng=g, **kw),
    "fog": lambda x, i, g, **kw: fog(x, i, visibility_m=60.0, rng=g, **kw),
}
WEATHERS = sorted(CALLS)


@pytest.fixture(scope="module")
def kitti_like():
    return street_frame(load_profile("hdl64e"), azimuths=360)


@pytest.fixture(scope="module")
def nuscenes_like():
    return street_frame(load_profile("hdl32e"), azimuths=360)


def run(weather, xyz, intensity, sensor="hdl64e", seed=0, **kw):
    return CALLS[weather](xyz, intensity, np.random.default_rng(seed), sensor=sensor, **kw)


# --- bad input ------------------------------------------------------------------------------


def test_every_error_is_a_lads_error():
    for cls in (ConfigError, InvalidPointsError, IntensityEncodingError):
        assert issubclass(cls, LadsError)


@pytest.mark.parametrize("weather", WEATHERS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinates_are_invalid_points(kitti_like, weather, bad):
    xyz, intensity = kitti_like[0].copy(), kitti_like[1]
    xyz[7, 1] = bad
    with pytest.raises(InvalidPointsError, match="NaN or infinite"):
        run(weather, xyz, intensity)


@pytest.mark.parametrize("weather", WEATHERS)
@pytest.mark.parametrize(
    ("sensor", "bad"), [("hdl64e", 1.5), ("hdl64e", -0.01), ("hdl64e", np.nan), ("hdl32e", 256.0)]
)
def test_intensity_outside_the_encoding_is_rejected(kitti_like, weather, sensor, bad):
    xyz, intensity = kitti_like[0], kitti_like[1].copy()
    intensity[3] = bad
    with pytest.raises(IntensityEncodingError):
        run(weather, xyz, intensity, sensor=sensor)


def test_0_255_intensities_on_a_unit_sensor_are_rejected(nuscenes_like):
    xyz, intensity = nuscenes_like
    with pytest.raises(IntensityEncodingError, match="hdl64e|encoding"):
        rain(xyz, intensity, rate_mm_h=5.0, sensor="hdl64e", rng=np.random.default_rng(0))


@pytest.mark.parametrize("weather", ["rain", "snow"])
@pytest.mark.parametrize("rate", [-1.0, np.nan, np.inf])
def test_bad_rate_is_a_config_error(kitti_like, weather, rate):
    simulate = {"rain": rain, "snow": snow}[weather]
    with pytest.raises(ConfigError):
        simulate(*kitti_like, rate_mm_h=rate, sensor="hdl64e", rng=np.random.default_rng(0))


@pytest.mark.parametrize("visibility", [0.0, -50.0, np.nan])
def test_bad_visibility_is_a_config_error(kitti_like, visibility):
    with pytest.raises(ConfigError):
        fog(*kitti_like, visibility_m=visibility, sensor="hdl64e", rng=np.random.default_rng(0))


@pytest.mark.parametrize("weather", WEATHERS)
@pytest.mark.parametrize("mode", ["first", "Strongest", ""])
def test_unknown_mode_is_a_config_error(kitti_like, weather, mode):
    with pytest.raises(ConfigError, match="mode"):
        run(weather, *kitti_like, mode=mode)


@pytest.mark.parametrize("weather", WEATHERS)
@pytest.mark.parametrize(
    ("xyz_shape", "intensity_shape"),
    [((10, 4), (10,)), ((10,), (10,)), ((10, 3), (9,)), ((10, 3), (10, 1)), ((3, 10), (3,))],
)
def test_wrong_shapes_are_invalid_points(weather, xyz_shape, intensity_shape):
    xyz = np.ones(xyz_shape, dtype=np.float32)
    intensity = np.full(intensity_shape, 0.1, dtype=np.float32)
    with pytest.raises(InvalidPointsError, match="shape"):
        run(weather, xyz, intensity)


# --- output contract ------------------------------------------------------------------------


def assert_contract(result, n):
    m = result.xyz.shape[0]
    assert result.xyz.dtype == np.float32 and result.xyz.shape == (m, 3)
    assert result.intensity.dtype == np.float32 and result.intensity.shape == (m,)
    assert result.source_index.dtype == np.int64 and result.source_index.shape == (m,)
    assert result.outcome.dtype == np.uint8 and result.outcome.shape == (m,)
    assert result.lost_index.dtype == np.int64
    # Dual mode may give a beam two adjacent points; otherwise one point per surviving beam.
    assert m + result.lost_index.size == n + result.second_returns
    assert np.all(np.diff(result.source_index) >= 0), "source_index is increasing"
    every = np.sort(np.r_[np.unique(result.source_index), result.lost_index])
    np.testing.assert_array_equal(every, np.arange(n))
    assert set(np.unique(result.outcome)) <= {Outcome.KEPT, Outcome.ATTENUATED, Outcome.PARTICLE}


@pytest.mark.parametrize("weather", WEATHERS)
def test_empty_frame_gives_an_empty_result(weather):
    result = run(weather, np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
    assert_contract(result, 0)
    assert result.xyz.shape == (0, 3)


@pytest.mark.parametrize("weather", WEATHERS)
@pytest.mark.parametrize("mode", ["strongest", "last", "dual"])
def test_labels_follow_their_beams_through_source_index(kitti_like, weather, mode):
    xyz, intensity = kitti_like
    labels = np.arange(len(xyz), dtype=np.uint32) * 7 + 3  # a label that names its point
    # Rain drops rarely reach the sensor's limit; the frame threshold lets some return here.
    frame_rule = {"params": with_overrides(RAIN_DEFAULTS, detection_threshold="frame")}
    result = run(weather, xyz, intensity, mode=mode, **(frame_rule if weather == "rain" else {}))
    assert_contract(result, len(xyz))
    out_labels = labels[result.source_index]
    np.testing.assert_array_equal((out_labels - 3) // 7, result.source_index)
    # Every output point lies on its source beam's ray (moved along it at most).
    src = xyz[result.source_index].astype(np.float64)
    out = result.xyz.astype(np.float64)
    cos = np.sum(src * out, axis=1) / (np.linalg.norm(src, axis=1) * np.linalg.norm(out, axis=1))
    assert np.all(cos > 1 - 1e-9)
    attenuated = result.outcome == Outcome.ATTENUATED
    assert attenuated.any() and (result.outcome == Outcome.PARTICLE).any()
    # Attenuated targets keep their range up to centimetre noise; particles come nearer, and
    # a fog echo at most half a pulse length (c tau_H / 2) beyond its target: the echo of
    # the fog just in front of a near target still spans the pulse.
    r_src, r_out = np.linalg.norm(src, axis=1), np.linalg.norm(out, axis=1)
    assert np.all(np.abs(r_out - r_src)[attenuated] < 0.1)
    reach = 0.5 * FOG_DEFAULTS.resolved_for(load_profile("hdl64e")).pulse_length_m
    slack = (reach if weather == "fog" else 0.0) + 1e-4  # float32 coordinates
    assert np.all(r_out[~attenuated] <= r_src[~attenuated] + slack)


@pytest.mark.parametrize("weather", WEATHERS)
def test_zero_range_rows_pass_through_unchanged(kitti_like, weather):
    """Zero-range rows (range <= 1e-6 m: "no return" placeholders) are not beams: they are
    KEPT with their input bytes and do not move the auto threshold."""
    xyz, intensity = kitti_like
    zero_rows = np.array([0, 5, len(xyz) + 1])
    n = len(xyz) + zero_rows.size
    keep = np.setdiff1d(np.arange(n), zero_rows)
    xyz_z = np.zeros((n, 3), np.float32)
    xyz_z[keep] = xyz
    xyz_z[5] = [1e-7, 0.0, 0.0]
    intensity_z = np.full(n, 0.37, np.float32)
    intensity_z[keep] = intensity
    profile = load_profile("hdl64e")
    assert auto_threshold(prepare_beams(xyz_z, intensity_z, profile)) == auto_threshold(
        prepare_beams(xyz, intensity, profile)
    )
    result = run(weather, xyz_z, intensity_z)
    assert_contract(result, n)
    pos = np.searchsorted(result.source_index, zero_rows)
    np.testing.assert_array_equal(result.source_index[pos], zero_rows)
    assert np.all(result.outcome[pos] == Outcome.KEPT)
    assert result.xyz[pos].tobytes() == xyz_z[zero_rows].tobytes()
    assert result.intensity[pos].tobytes() == intensity_z[zero_rows].tobytes()


@pytest.mark.parametrize("weather", WEATHERS)
def test_frame_of_only_zero_range_rows_is_returned_unchanged(weather):
    xyz = np.zeros((4, 3), np.float32)
    intensity = np.full(4, 0.2, np.float32)
    result = run(weather, xyz, intensity)
    assert np.all(result.outcome == Outcome.KEPT) and result.lost_index.size == 0
    assert result.xyz.tobytes() == xyz.tobytes()


KITTI_LEVELS = (np.arange(100) / 100).astype(np.float32)  # float32(k / 100), k = 0..99


@pytest.mark.parametrize("weather", WEATHERS)
def test_kitti_output_intensities_lie_on_the_0_01_grid(kitti_like, weather):
    result = run(weather, *kitti_like)
    moved = result.outcome != Outcome.KEPT
    assert moved.any()
    assert np.all(np.isin(result.intensity, KITTI_LEVELS))
    assert result.intensity.min() >= 0 and result.intensity.max() <= np.float32(0.99)


@pytest.mark.parametrize("weather", WEATHERS)
def test_byte_sensor_output_intensities_are_integers_0_to_255(nuscenes_like, weather):
    result = run(weather, *nuscenes_like, sensor="hdl32e")
    values = result.intensity
    assert np.all(values == np.round(values))
    assert values.min() >= 0 and values.max() <= 255


# --- fog does not flood light-fog frames (Hahner's rounding bug) ----------------------------


def byte_twin(profile_name="hdl64e"):
    """The same sensor with nuScenes' 0-255 encoding (full scale 100, step 1)."""
    base = load_profile(profile_name)
    return dataclasses.replace(base, intensity=load_profile("hdl32e").intensity)


def fog_share(xyz, intensity, sensor, visibility_m, mode="strongest"):
    result = fog(
        xyz,
        intensity,
        visibility_m=visibility_m,
        sensor=sensor,
        mode=mode,
        rng=np.random.default_rng(0),
    )
    return result.counts()["particle"] / len(xyz)


@pytest.mark.parametrize("visibility_m", [1000.0, 200.0, 50.0])
def test_fog_does_not_depend_on_the_intensity_encoding(kitti_like, visibility_m):
    """The same scene in [0, 1] and in 0-255 gives the same fog share (Hahner rounded
    intensities as if 0-255: on [0, 1] data 86-99.8 % of points became fog)."""
    xyz, intensity = kitti_like
    twin = byte_twin()
    as_bytes = twin.intensity.from_reflectivity(
        load_profile("hdl64e").intensity.to_reflectivity(intensity)
    )
    unit_share = fog_share(xyz, intensity, "hdl64e", visibility_m)
    byte_share = fog_share(xyz, as_bytes, twin, visibility_m)
    assert unit_share == pytest.approx(byte_share, abs=0.002)


@pytest.mark.parametrize("sensor", ["hdl64e", "hdl32e"])
def test_light_fog_in_last_mode_keeps_nearly_every_target(kitti_like, nuscenes_like, sensor):
    xyz, intensity = kitti_like if sensor == "hdl64e" else nuscenes_like
    assert fog_share(xyz, intensity, sensor, 1000.0, mode="last") < 0.01


@pytest.mark.parametrize("sensor", ["hdl64e", "hdl32e"])
def test_light_fog_leaves_more_than_90_percent_of_points_as_targets(
    kitti_like, nuscenes_like, sensor
):
    xyz, intensity = kitti_like if sensor == "hdl64e" else nuscenes_like
    assert fog_share(xyz, intensity, sensor, 1000.0) < 0.10


# --- LISA's published settings ---------------------------------------------------------------


@pytest.mark.parametrize("weather", ["rain", "snow"])
def test_lisa_settings_drop_a_weak_clear_air_return_that_lads_keeps_in_light_weather(
    kitti_like, weather
):
    from lads.physics.weather import LISA_RAIN, LISA_SNOW, settings_for

    xyz, intensity = kitti_like[:2]
    lisa = settings_for(weather, "lisa")
    assert lisa is (LISA_RAIN if weather == "rain" else LISA_SNOW)
    # A weak far return: detected in clear air, below LISA's 0.9 / 200^2 even before rain.
    weak = np.array([[70.0, 0.0, -1.0]], dtype=np.float32)
    xyz = np.concatenate([xyz, weak])
    intensity = np.concatenate([intensity, np.float32([0.02])]).astype(np.float32)
    assert 0.02 / 70.0**2 < lisa.detection_threshold
    simulate = rain if weather == "rain" else snow
    kept_ours = kept_lisa = 0
    for seed in range(20):
        for params, counter in ((settings_for(weather, "lads"), "ours"), (lisa, "lisa")):
            result = simulate(
                xyz,
                intensity,
                rate_mm_h=0.01,
                sensor="hdl64e",
                params=params,
                rng=np.random.default_rng(seed),
            )
            kept = len(xyz) - 1 not in result.lost_index
            if counter == "ours":
                kept_ours += kept
            else:
                kept_lisa += kept
                assert result.detection_threshold == pytest.approx(0.9 / 200.0**2)
    # Ours: the point was detected, so light weather keeps it almost always; LISA never.
    assert kept_ours >= 17 and kept_lisa == 0


def test_fog_has_no_lisa_settings_and_unknown_settings_are_refused():
    from lads.physics.weather import FOG_DEFAULTS, settings_for

    assert settings_for("fog", "lads") is FOG_DEFAULTS
    with pytest.raises(ConfigError, match="no fog model"):
        settings_for("fog", "lisa")
    with pytest.raises(ConfigError, match="expected one of"):
        settings_for("rain", "carla")


@pytest.mark.parametrize("weather", WEATHERS)
def test_dual_returns_hold_the_strongest_first_and_the_last_where_it_differs(kitti_like, weather):
    """A dual frame holds each beam's strongest return first and its last (or, where the
    target is both, the particle in front of it) second."""
    xyz, intensity = kitti_like
    frame_rule = {"params": with_overrides(RAIN_DEFAULTS, detection_threshold="frame")}
    kw = frame_rule if weather == "rain" else {}
    dual = run(weather, xyz, intensity, mode="dual", **kw)
    assert np.all(np.diff(dual.source_index) >= 0)
    first = np.r_[True, np.diff(dual.source_index) != 0]
    assert dual.second_returns == int((~first).sum()) > 0
    # Pairs: a particle (or fog echo) then the target or a farther particle; or a target
    # then the particle in front of it (Velodyne's second strongest).
    second = np.flatnonzero(~first)
    before = second - 1
    r = np.linalg.norm(dual.xyz.astype(np.float64), axis=1)
    behind = dual.outcome[before] == Outcome.PARTICLE
    reach = 0.5 * FOG_DEFAULTS.resolved_for(load_profile("hdl64e")).pulse_length_m
    slack = (reach if weather == "fog" else 0.0) + 1e-4  # float32 coordinates
    assert np.all(r[second][behind] > r[before][behind] - slack)
    assert np.all(dual.outcome[before][~behind] == Outcome.ATTENUATED)
    assert np.all(dual.outcome[second][~behind] == Outcome.PARTICLE)
    # A flake or fog echo in front: nearer than its target's source range (a fog echo, timed
    # less precisely, is reported at most half a pulse beyond it, fog.py).
    r_target = np.linalg.norm(xyz[dual.source_index[second]].astype(np.float64), axis=1)
    assert np.all(r[second][~behind] <= r_target[~behind] + slack)
    # No beam is both lost and returned; every beam is accounted for once.
    assert not np.isin(dual.lost_index, dual.source_index).any()
    assert np.unique(dual.source_index).size + dual.lost_index.size == len(xyz)


def test_dual_mode_is_refused_with_aligned_points():
    from lads.config import PipelineConfig, StageConfig

    with pytest.raises(ConfigError, match="aligned tree keeps one row per source beam"):
        PipelineConfig(
            variant="x",
            stages=(StageConfig("snow", {"rate_mm_h": 1.0, "mode": "dual"}),),
            points="aligned",
        )
