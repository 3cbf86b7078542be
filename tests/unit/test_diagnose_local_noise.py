"""The point noise's range slope from neighbouring returns of one surface
(lads/diagnose/local_noise.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lads.diagnose.design import paired_design
from lads.diagnose.local_noise import local_noise, neighbour_pairs
from tests.unit.test_diagnose_localize import make_table


def surfaces(seed: int, slope: float, surface_sd: float = 0.3, sigma_m10: float = 0.05):
    """Surfaces of 100 returns each along one ring, 0.2 deg apart at one range; the real
    value = sim x exp(surface offset + point noise), point noise sd sigma_m10 (R / 10)^slope."""
    table = make_table(seed, noise=0.0, drop=lambda r: np.zeros(r.shape))
    rng = np.random.default_rng(seed + 7)
    n = len(table)
    g = np.arange(n) // 100
    j = np.arange(n) % 100
    n_groups = g.max() + 1
    centre = np.exp(rng.uniform(np.log(3.0), np.log(60.0), n_groups))
    range_m = (centre[g] * (1.0 + 0.001 * rng.standard_normal(n))).astype(np.float32)
    azimuth = np.mod(rng.uniform(0, 300, n_groups)[g] + 0.2 * j, 360.0).astype(np.float32)
    ring = (g % 64).astype(np.int16)
    i_sim = np.round(np.exp(rng.uniform(np.log(0.15), np.log(0.5), n)), 2)
    sd = sigma_m10 * (range_m / 10.0) ** slope
    real = i_sim * np.exp(rng.normal(0, surface_sd, n_groups)[g] + sd * rng.standard_normal(n))
    return dataclasses.replace(
        table,
        range_m=range_m,
        azimuth_deg=azimuth,
        ring=ring,
        class_id=np.full(n, 50, np.int32),
        ret_sim=np.ones(n, bool),
        ret_real=np.ones(n, bool),
        i_sim=i_sim.astype(np.float32),
        i_real=np.clip(np.round(real, 2), 0, 0.99).astype(np.float32),
    )


@pytest.mark.parametrize("slope", [0.0, 0.75])
def test_the_point_noise_slope_is_found_under_a_larger_surface_spread(slope):
    design = paired_design(surfaces(31, slope))
    rows = np.arange(len(design))
    # The prediction itself: any per-surface offset cancels in the differences.
    mu = design.ln_sim.numpy()
    fit = local_noise(design, mu, rows, float(np.log(10.0)))
    assert fit is not None and fit.pairs > 5000
    assert fit.range_slope == pytest.approx(slope, abs=0.12)
    assert np.exp(fit.ln_sigma) == pytest.approx(0.05, rel=0.3)
    assert (abs(fit.z) > 5) == (slope > 0)


def test_neighbour_pairs_stay_on_one_ring_and_surface_and_share_no_return():
    design = paired_design(surfaces(32, 0.0))
    pairs = neighbour_pairs(design, np.arange(len(design)))
    ring, az = design.ring.numpy(), design.azimuth_deg.numpy()
    assert (ring[pairs[:, 0]] == ring[pairs[:, 1]]).all()
    assert (np.abs(az[pairs[:, 0]] - az[pairs[:, 1]]) <= 0.5).all()
    assert len(np.unique(pairs)) == pairs.size
