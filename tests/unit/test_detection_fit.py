"""The detection limit measured from clear frames recovers a known limit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from lads.errors import ConfigError
from lads.sensors.detection_fit import fit_detection_limit, level_counts
from lads.sensors.profile import load_profile


def _synthetic_scan(limit_power: float, spread_ln: float, n: int, seed: int):
    """Returns a sensor with the given limit would report from targets spread over 10-100 m
    with one reflectivity mix at every range (HDL-32E encoding: intensity = 100 rho)."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(10.0, 100.0, n)
    intensity = np.clip(np.rint(rng.lognormal(np.log(12.0), 0.9, n)), 0, 100)
    rho = np.maximum(intensity / 100.0, 0.005)
    p = ndtr((np.log(rho / r**2) - np.log(limit_power)) / spread_ln)
    seen = rng.random(n) < p
    return r[seen], intensity[seen].astype(np.float32)


@pytest.mark.parametrize(("limit_power", "spread_ln"), [(4e-5, 0.4), (1e-5, 0.7)])
def test_fit_recovers_a_known_limit_and_spread(limit_power: float, spread_ln: float) -> None:
    r, intensity = _synthetic_scan(limit_power, spread_ln, 400_000, seed=3)
    fit = fit_detection_limit(r, intensity, load_profile("hdl32e"))
    assert fit.limit_power == pytest.approx(limit_power, rel=0.1)
    assert fit.spread_ln == pytest.approx(spread_ln, rel=0.1)
    assert fit.range_for(0.1) == pytest.approx(np.sqrt(0.1 / fit.limit_power))


def test_counts_keep_diffuse_returns_in_the_window_only() -> None:
    r = np.array([5.0, 12.2, 12.7, 30.0, 30.5, 150.0])
    intensity = np.array([10, 0, 10, 10, 200, 10], dtype=np.float32)  # 200: retro-reflector
    counts, r_bin, levels = level_counts(r, intensity, load_profile("hdl32e"))
    assert counts.sum() == 3  # not the 5 m, retro or beyond-max-range returns
    assert levels == pytest.approx([0.005, 0.1])  # a stored 0 sits at the half step
    assert r_bin == pytest.approx([12.45, 30.0])
    with pytest.raises(ConfigError, match="no diffuse returns"):
        level_counts(np.array([3.0]), np.array([5.0]), load_profile("hdl32e"))
