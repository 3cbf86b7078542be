"""The detection rule (lads.physics.detection) against its equations (docs/physics.md §9.7)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from lads.errors import ConfigError, SensorProfileError
from lads.physics.detection import resolve_detection, target_survival
from lads.resources import sensors_dir
from lads.sensors.profile import load_profile


def test_clear_air_loses_nothing_whatever_the_stored_power():
    power = np.array([1e-9, 1e-6, 4e-5, 1e-3, 1.0])
    survival = target_survival(np.maximum(power, 4e-5), np.zeros(5), 4e-5, 0.5)
    np.testing.assert_array_equal(survival, 1.0)


def test_survival_is_the_latent_noise_probability_conditioned_on_clear_detection():
    """Monte Carlo of the model's meaning: one receiver noise e ~ N(0, s^2) per beam; seen
    in clear air iff ln P + e >= ln P_lim, in weather iff ln P + ln T^2 + e >= ln P_lim."""
    limit, spread = 4e-5, 0.5
    power = np.array([4e-5, 6e-5, 2e-4, 1e-3])
    two_way_ln = np.array([-0.3, -0.3, -0.6, -1.5])
    e = spread * np.random.default_rng(0).standard_normal((400_000, 1))
    clear = np.log(power) + e >= np.log(limit)
    weather = np.log(power) + two_way_ln + e >= np.log(limit)
    expected = (clear & weather).sum(axis=0) / clear.sum(axis=0)
    survival = target_survival(power, two_way_ln, limit, spread)
    np.testing.assert_allclose(survival, expected, atol=0.005)
    assert np.all(np.diff(survival[:2]) > 0)  # stronger returns survive more often


def test_targets_below_the_limit_are_taken_at_the_limit():
    rule = resolve_detection("sensor", 4e-5, 0.5, 1e-7)
    np.testing.assert_array_equal(rule.effective_power(np.array([1e-7, 1e-3])), [4e-5, 1e-3])
    # The frame and fixed rules take stored powers as they are.
    assert resolve_detection("frame", 4e-5, 0.5, 1e-7).effective_power(np.array([1e-7]))[0] == 1e-7
    assert resolve_detection(2e-5, 4e-5, 0.5, 1e-7).setting == "fixed"


def test_detection_draws_only_where_survival_is_uncertain():
    rule = resolve_detection("sensor", 4e-5, 0.5, 1e-7)
    clear = np.array([1.0, 1.0, 4e-5, 4e-5])
    two_way_ln = np.array([-0.01, -0.01, -0.5, -0.5])
    active = np.array([True, False, True, True])
    rng = np.random.default_rng(3)
    detected, power = rule.targets_detected(clear, two_way_ln, active, rng)
    assert detected[0] and not detected[1]
    np.testing.assert_allclose(power, clear * np.exp(two_way_ln))
    # Two uniforms were drawn (the two uncertain beams), no more.
    assert rng.bit_generator.state == _after_draws(3, 2)


def _after_draws(seed, n):
    rng = np.random.default_rng(seed)
    rng.random(n)
    return rng.bit_generator.state


@pytest.mark.parametrize("bad", ["datasheet", 0.0, -1e-5, float("nan"), float("inf")])
def test_malformed_rules_are_refused(bad):
    with pytest.raises(ConfigError, match="detection_threshold"):
        resolve_detection(bad, 4e-5, 0.5, 1e-7)


def test_every_shipped_profile_has_a_documented_detection_limit():
    for path in sorted(sensors_dir().glob("*.yaml")):
        profile = load_profile(path.stem)
        assert profile.detection.power > 0
        assert any(s.startswith("detection:") for s in profile.sources), path


def test_a_profile_without_detection_limit_names_the_missing_key(tmp_path):
    raw = yaml.safe_load((sensors_dir() / "hdl64e.yaml").read_text())
    del raw["detection"]
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(SensorProfileError, match="detection"):
        load_profile(path)


def test_the_limit_power_is_reflectivity_over_range_squared():
    limit = load_profile("hdl64e").detection
    assert limit.power == pytest.approx(limit.reflectivity / limit.range_m**2)
    assert dataclasses.is_dataclass(limit)


def _exact_draws(clear, two_way_ln, active, rule, seed):
    """The rule's definition: q exact for every beam, one uniform per active beam whose
    q < 1 (in beam order), detected iff u < q."""
    effective = rule.effective_power(clear)
    survival = target_survival(effective, two_way_ln, rule.threshold, rule.spread_ln)
    rng = np.random.default_rng(seed)
    detected = active.copy()
    uncertain = np.flatnonzero(active & (survival < 1.0))
    detected[uncertain] = rng.random(uncertain.size) < survival[uncertain]
    return detected, rng.bit_generator.state


def _hard_cases(n, rng):
    """Targets from just above the limit to far above it, weather from none to heavy; many
    survivals within 1e-12 of 1 (clear or almost clear paths), some exactly 1."""
    limit = 4e-5
    clear = limit * np.exp(rng.uniform(0.0, 6.0, n))
    two_way_ln = -np.concatenate(
        [
            rng.uniform(0.0, 3.0, n // 2),
            10.0 ** rng.uniform(-14, -2, n - n // 2 - 20),
            np.zeros(20),
        ]
    )
    active = rng.random(n) < 0.95
    return clear, two_way_ln, active


@pytest.mark.parametrize("tolerance", [None, 0.05])
def test_screened_draws_equal_the_exact_rule_draw_for_draw(monkeypatch, tolerance):
    """The tabulated screen (`targets_detected`) must decide every beam as the exact q does
    and draw the same uniforms; a wide tolerance sends many draws to the exact fallback."""
    import lads.physics.detection as detection

    if tolerance is not None:
        monkeypatch.setattr(detection, "SCREEN_TOLERANCE", tolerance)
    rule = resolve_detection("sensor", 4e-5, 0.39, 1e-7)
    clear, two_way_ln, active = _hard_cases(200_000, np.random.default_rng(5))
    rng = np.random.default_rng(8)
    detected, _ = rule.targets_detected(clear, two_way_ln, active, rng)
    want, state = _exact_draws(clear, two_way_ln, active, rule, 8)
    np.testing.assert_array_equal(detected, want)
    assert rng.bit_generator.state == state
    assert 0 < (active & ~detected).sum() < active.sum()


def test_the_phi_table_keeps_its_error_bound():
    """|q_table - q| stays below a fifth of the screen's tolerance (its stated margin)."""
    import lads.physics.detection as detection
    from lads.physics.kernels import APPROX, survival_screen

    rng = np.random.default_rng(2)
    z = rng.uniform(0.0, 12.0, 400_000)
    z_weather = z - rng.uniform(0.0, 20.0, z.size) ** 2 / 20
    q, state = survival_screen(
        z,
        z_weather,
        np.ones(z.size, dtype=bool),
        detection._phi_table(),
        detection.PHI_TABLE_START,
        detection.PHI_STEPS_PER_UNIT,
        detection.CERTAIN_Z,
        detection.SCREEN_TOLERANCE,
    )
    shown = state == APPROX
    exact = detection._survival_ratio(z[shown], z_weather[shown])
    assert np.abs(q[shown] - exact).max() < detection.SCREEN_TOLERANCE / 5
    assert (exact < 1.0).all() and shown.sum() > 300_000
