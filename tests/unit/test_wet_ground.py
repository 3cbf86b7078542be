"""Wet ground (lads.physics.wet_ground) against its equations (docs/physics.md §8.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lads.config import load_pipeline
from lads.errors import ConfigError
from lads.physics.materials import wet_surface_for_labels
from lads.physics.result import Outcome
from lads.physics.wet_ground import (
    WATER_REFRACTIVE_INDEX,
    WetGroundParams,
    fresnel_unpolarised,
    internal_diffuse_reflectance,
    wet_ground,
    wet_ratio,
)
from lads.resources import pipelines_dir

N = WATER_REFRACTIVE_INDEX
ROAD, BUILDING, LANE = 40, 50, 60


def _scene(ranges=None):
    """Flat road 1.73 m below the sensor at the given ranges, plus a building wall."""
    ranges = np.linspace(3.0, 60.0, 400) if ranges is None else ranges
    h = 1.73
    d = np.sqrt(ranges**2 - h**2)
    road = np.stack([d, np.zeros_like(d), np.full_like(d, -h)], axis=1)
    wall = np.stack([np.full(50, 15.0), np.linspace(-5, 5, 50), np.linspace(-1, 3, 50)], axis=1)
    xyz = np.concatenate([road, wall]).astype(np.float32)
    intensity = np.concatenate([np.full(len(road), 0.12), np.full(50, 0.3)]).astype(np.float32)
    labels = np.concatenate([np.full(len(road), ROAD), np.full(50, BUILDING)]).astype(np.uint32)
    return xyz, intensity, labels


def _snell_fresnel(theta_i: float, n1: float, n2: float) -> float:
    """Unpolarised Fresnel reflectance from medium n1 into n2 at incidence theta_i (radians),
    written from Snell's law and the angle forms, 1 beyond the critical angle."""
    s = n1 / n2 * math.sin(theta_i)
    if s >= 1.0:
        return 1.0
    theta_t = math.asin(s)
    if theta_i == 0.0:
        return ((n1 - n2) / (n1 + n2)) ** 2
    r_s = math.sin(theta_i - theta_t) ** 2 / math.sin(theta_i + theta_t) ** 2
    r_p = math.tan(theta_i - theta_t) ** 2 / math.tan(theta_i + theta_t) ** 2
    return 0.5 * (r_s + r_p)


def test_fresnel_matches_the_angle_forms_and_its_limits():
    thetas = np.radians([0.0, 20.0, 45.0, 70.0, 85.0])
    ours = fresnel_unpolarised(np.cos(thetas), N)
    ref = [_snell_fresnel(float(t), 1.0, N) for t in thetas]
    np.testing.assert_allclose(ours, ref, rtol=1e-9, atol=1e-12)
    assert fresnel_unpolarised(np.array([1.0]), N)[0] == pytest.approx(((N - 1) / (N + 1)) ** 2)
    assert fresnel_unpolarised(np.array([0.0]), N)[0] == pytest.approx(1.0)


def test_internal_reflectance_is_the_cosine_weighted_mean_seen_from_the_water():
    """Integrated from the water side (total internal reflection beyond the critical angle),
    independently of the reciprocity form the module uses."""
    thetas = np.linspace(0.0, 0.5 * math.pi, 20001)
    r = np.array([_snell_fresnel(float(t), N, 1.0) for t in thetas])
    f = r * 2.0 * np.sin(thetas) * np.cos(thetas)
    direct = float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(thetas)))  # trapezoid rule
    assert internal_diffuse_reflectance(N) == pytest.approx(direct, abs=2e-4)


def test_wet_ratio_follows_its_equation_and_its_limits():
    params = WetGroundParams(water_film_mm=1.0)
    cos_i = np.array([1.0, 0.5, 0.1])
    albedo = np.full(3, 0.1)
    t = np.full(3, 1.0)
    r = fresnel_unpolarised(cos_i, N)
    cos_t = np.sqrt(1 - (1 - cos_i**2) / N**2)
    expected = (
        (1 - r) ** 2
        / N**2
        / (1 - 0.1 * internal_diffuse_reflectance(N))
        * np.exp(-2 * params.absorption_per_m * 1e-3 / cos_t)
    )
    np.testing.assert_allclose(wet_ratio(cos_i, albedo, t, params), expected, rtol=1e-12)
    # A film half the texture depth covers half the surface; no film changes nothing.
    half = wet_ratio(cos_i, albedo, np.full(3, 2.0), params)
    np.testing.assert_allclose(half, 0.5 + 0.5 * expected, rtol=1e-12)
    dry = wet_ratio(cos_i, albedo, t, WetGroundParams(0.0))
    np.testing.assert_array_equal(dry, 1.0)
    assert np.all(np.diff(expected) < 0)  # darker towards grazing incidence


def test_only_ground_classes_get_wet_and_other_points_keep_their_bytes():
    xyz, intensity, labels = _scene()
    res = wet_ground(
        xyz,
        intensity,
        labels,
        "semantickitti",
        sensor="hdl64e",
        rng=np.random.default_rng(0),
        params=WetGroundParams(1.2),
    )
    wall = np.flatnonzero(labels == BUILDING)
    pos = np.searchsorted(res.source_index, wall)
    assert np.all(res.outcome[pos] == Outcome.KEPT)
    assert res.xyz[pos].tobytes() == xyz[wall].tobytes()
    assert res.intensity[pos].tobytes() == intensity[wall].tobytes()
    road_out = labels[res.source_index] == ROAD
    assert np.all(res.outcome[road_out] == Outcome.ATTENUATED)
    assert np.all(res.intensity[road_out] < intensity[res.source_index[road_out]])
    assert np.all(labels[res.lost_index] == ROAD) and res.lost_index.size > 0
    # Far (grazing) road goes first.
    r_lost = np.linalg.norm(xyz[res.lost_index], axis=1)
    assert np.median(r_lost) > 30.0


def test_no_film_and_no_ground_change_nothing():
    xyz, intensity, labels = _scene()
    for params, lab in ((WetGroundParams(0.0), labels), (WetGroundParams(1.0), labels * 0 + 50)):
        res = wet_ground(
            xyz,
            intensity,
            lab,
            "semantickitti",
            sensor="hdl64e",
            rng=np.random.default_rng(0),
            params=params,
        )
        assert res.lost_index.size == 0 and np.all(res.outcome == Outcome.KEPT)
        assert res.intensity.tobytes() == intensity.tobytes()


def test_the_same_generator_gives_the_same_bytes():
    xyz, intensity, labels = _scene()
    runs = [
        wet_ground(
            xyz,
            intensity,
            labels,
            "semantickitti",
            sensor="hdl64e",
            rng=np.random.default_rng(7),
            params=WetGroundParams(0.5),
        )
        for _ in range(2)
    ]
    assert runs[0].xyz.tobytes() == runs[1].xyz.tobytes()
    np.testing.assert_array_equal(runs[0].lost_index, runs[1].lost_index)


def test_loss_matches_a_per_point_brute_force_with_latent_receiver_noise():
    """Brute force: per road point, g from the angle forms, a latent noise e drawn by rejection
    so that the point was seen in clear air, seen again iff ln(P_eff g) + e >= ln P_lim."""
    from lads.sensors.profile import load_profile

    xyz, intensity, labels = _scene(np.linspace(4.0, 40.0, 2000))
    profile = load_profile("hdl64e")
    limit, s = profile.detection.power, profile.detection.spread_ln
    params = WetGroundParams(1.2)
    rng = np.random.default_rng(11)
    brute_lost = 0
    road = labels == ROAD
    for p, rho in zip(xyz[road].astype(np.float64), intensity[road], strict=True):
        r = float(np.linalg.norm(p))
        theta = math.acos(-p[2] / r)
        theta_t = math.asin(math.sin(theta) / N)
        transmit = 1 - _snell_fresnel(theta, 1.0, N)
        g = (
            transmit**2
            / N**2
            / (1 - 0.10 * internal_diffuse_reflectance(N))
            * math.exp(-2 * params.absorption_per_m * 1.2e-3 / math.cos(theta_t))
        )
        p_eff = max(float(rho) / r**2, limit)
        while True:
            e = s * rng.standard_normal()
            if math.log(p_eff) + e >= math.log(limit):
                break
        brute_lost += math.log(p_eff * g) + e < math.log(limit)
    runs = 20
    fast_lost = (
        sum(
            wet_ground(
                xyz,
                intensity,
                labels,
                "semantickitti",
                sensor=profile,
                rng=np.random.default_rng(k),
                params=params,
            ).lost_index.size
            for k in range(runs)
        )
        / runs
    )
    n_road = int((labels == ROAD).sum())
    p_brute, p_fast = brute_lost / n_road, fast_lost / n_road
    assert 0.05 < p_brute < 0.95
    # Standard error of the brute force's single run dominates: allow 4 of them.
    assert abs(p_fast - p_brute) < 4 * math.sqrt(p_brute * (1 - p_brute) / n_road)


def test_ground_classes_and_texture_depths_come_from_materials_yaml():
    wettable, depth = wet_surface_for_labels(
        np.array([ROAD, LANE, BUILDING, (3 << 16) | ROAD]), "semantickitti"
    )
    np.testing.assert_array_equal(wettable, [True, True, False, True])
    assert depth[0] > depth[1] > 0 and depth[2] == 0


def test_rain_pipeline_wets_the_road_and_severity_sets_both_stages():
    rain = load_pipeline(pipelines_dir() / "rain.yaml")
    assert [s.stage for s in rain.stages] == ["rain", "wet_ground"]
    light = rain.with_overrides(severity="light")
    film = dict(light.stages[1].params)
    assert film["water_film_mm"] == 0.2 and light.stages[0].params["rate_mm_h"] == 1.0
    with pytest.raises(ConfigError, match="water film"):
        rain.with_overrides(water_film_mm=-1.0)
