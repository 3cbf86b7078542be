"""Point noise from neighbouring returns: what the shared reflectance of a surface hides."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lads.diagnose.data.table import BeamTable
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.from_table import paired_design
from lads.diagnose.verdict.heldout import POINT_NOISE_MIN_SLOPE
from lads.diagnose.verdict.point_noise import neighbour_pairs, point_noise
from tests.unit.test_diagnose_localize import make_table

ROWS = 100  # returns per surface
SPACING_DEG = 0.2


def surfaces(seed: int, point_sd, *, surface_sd: float = 0.3, n_scans: int = 6) -> BeamTable:
    """Surfaces of ROWS returns each, side by side on one ring at one range (1.5-110 m),
    each with its own reflectance offset (sd `surface_sd` in ln I) and point noise of sd
    `point_sd(range_m)`."""
    base = make_table(seed, n_scans=n_scans, rows_per_group=ROWS)
    rng = np.random.default_rng(seed + 1)
    n = len(base.range_m)
    g = np.arange(n) // ROWS
    k = np.arange(n) % ROWS
    n_groups = int(g.max()) + 1
    centre_m = np.exp(rng.uniform(np.log(1.5), np.log(110.0), n_groups))
    range_m = centre_m[g] * (1.0 + 1e-4 * k)
    azimuth = (rng.uniform(0, 300, n_groups)[g] + SPACING_DEG * k) % 360.0
    h = base.sensor.half_step
    # The simulation stored its value rounded; reality follows the unrounded one.
    unrounded = np.maximum(base.i_sim + rng.uniform(-h, h, n), 0.0)
    ln_real = (
        np.log(unrounded + h)
        + rng.normal(0.0, surface_sd, n_groups)[g]
        + rng.normal(0.0, 1.0, n) * point_sd(range_m)
    )
    # Stored as a sensor stores it: rounded to the encoding's step.
    i_real = np.where(
        base.ret_sim & np.isfinite(base.i_real),
        np.round((np.exp(ln_real) - h) / (2 * h)) * (2 * h),
        base.i_real,
    )
    return dataclasses.replace(
        base,
        ring=(g % 64).astype(np.int16),
        azimuth_deg=azimuth.astype(np.float32),
        range_m=range_m.astype(np.float32),
        i_real=i_real.astype(np.float32),
    )


def noise_of(design: Design) -> dict:
    mu = design.ln_sim.numpy() + float(np.median((design.y - design.ln_sim).numpy()))
    odd = (np.unique(design.group, return_inverse=True)[1] % 5) == 0
    rows = np.arange(len(design))
    ln_r = float(design.ln_range.mean())
    ln_s = float(design.ln_sim.mean())
    return point_noise(design, mu, rows[~odd], rows[odd], ln_r, ln_s, POINT_NOISE_MIN_SLOPE, 3.0)


def test_neighbours_are_consecutive_returns_of_one_surface():
    design = paired_design(surfaces(1, lambda r: np.full(r.shape, 0.05)))
    mu = design.ln_sim.numpy()
    pairs = neighbour_pairs(design, mu)
    # Rows fitted as exact values (returned, clear of the rounding floor) pair up with the
    # next such row of their surface, across one lost or censored return at most.
    exact = int((design.fits_intensity & (design.censor.numpy() == 0)).sum())
    assert len(pairs) > 0.8 * exact
    assert np.all(design.group[pairs.i] == design.group[pairs.j])
    assert np.all(design.ring.numpy()[pairs.i] == design.ring.numpy()[pairs.j])
    gap = design.azimuth_deg.numpy()[pairs.j] - design.azimuth_deg.numpy()[pairs.i]
    assert np.all((gap > 0) & (gap < 2.6 * SPACING_DEG))


def test_point_noise_growing_with_range_is_found_under_a_larger_surface_spread():
    # sigma 0.03 at 5 m, 0.36 at 110 m, under a surface spread of 0.3 shared by neighbours.
    design = paired_design(surfaces(2, lambda r: 0.03 * (r / 5.0) ** 0.8))
    noise = noise_of(design)
    assert noise["kind"] == "heteroscedastic"
    lo, hi = noise["range_slope_ci95"]
    assert lo < 0.8 < hi
    assert abs(noise["level_slope"]) < 0.1  # the level is independent of range here
    assert noise["heldout_gain_nats"]["z"] > 3.0


def test_the_model_free_scale_per_range_bin_follows_the_true_noise_and_the_fitted_law():
    true_sd = lambda r: 0.03 * (r / 5.0) ** 0.8  # noqa: E731
    noise = noise_of(paired_design(surfaces(2, true_sd)))
    bins = noise["by_range"]
    assert len(bins) >= 5
    for b in bins:
        assert b["sigma_ln_i"] == pytest.approx(true_sd(b["range_m"]), rel=0.2)
        assert b["fitted_sigma_ln_i"] == pytest.approx(b["sigma_ln_i"], rel=0.2)


@pytest.mark.parametrize("sigma", [0.08, 0.03])
def test_constant_point_noise_under_surface_spread_is_homoscedastic(sigma):
    # At 0.03 the rounding of values ~10 steps above 0 is as large as the noise. Its
    # variance is removed; what is left (a level slope of ~0.1: Gaussian plus uniform is
    # not a t) stays below the slope that matters (analysis.POINT_NOISE_MIN_SLOPE).
    design = paired_design(surfaces(3, lambda r: np.full(r.shape, sigma)))
    noise = noise_of(design)
    assert noise["kind"] == "homoscedastic"
    assert abs(noise["range_slope"]) < 0.05
    assert abs(noise["level_slope"]) < 0.5 * POINT_NOISE_MIN_SLOPE
    # The point noise, not the surfaces' 0.3.
    assert noise["sigma_ln_i_if_gaussian"] == pytest.approx(sigma, rel=0.1)


def test_too_few_neighbours_leave_the_noise_undetermined_with_the_reason():
    table = surfaces(4, lambda r: np.full(r.shape, 0.05), n_scans=1)
    keep = np.flatnonzero(np.arange(len(table.range_m)) % ROWS < 3)
    design = paired_design(table.take(keep))
    noise = noise_of(design)
    assert noise["kind"] == "undetermined"
    assert "neighbour pairs" in noise["reason"]
