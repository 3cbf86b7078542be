"""The compiled fog-echo loop gives the bytes of the numpy expressions it replaces."""

from __future__ import annotations

import numpy as np

from lads.physics.fog_kernels import KAPPA_FLOOR_PER_M2, KAPPA_RATIO_CAP, echo_ranges


def _numpy_reference(r0, pf, reported, noise, grid, curvature, p_min, kappa_pulse, dr, half,
                     min_range):  # fmt: skip
    """The echo rule as numpy expressions (docs/physics.md §7): curvature looked up by
    np.interp, sigma = min(dR / sqrt(2 SNR) * min(kappa_pulse / kappa, cap), 1 / sqrt(kappa)),
    range clipped to [min_range, r0 + half a pulse], reflectivity P_f r^2."""
    kappa = np.maximum(np.interp(r0, grid, curvature), KAPPA_FLOOR_PER_M2)
    timing = dr / np.sqrt(2.0 * (pf / p_min)) * np.minimum(kappa_pulse / kappa, KAPPA_RATIO_CAP)
    sigma = np.minimum(timing, 1.0 / np.sqrt(kappa))
    out_r = np.clip(reported + sigma * noise, min_range, r0 + half)
    return out_r, pf * out_r**2


def test_echo_ranges_match_numpy_bit_for_bit_on_every_branch():
    rng = np.random.default_rng(7)
    grid = np.linspace(3.25, 7.9, 94)
    curvature = rng.uniform(0.0, 40.0, grid.size)
    curvature[:3] = 0.0  # the curvature floor
    curvature[10:12] = 1e-9  # the ratio cap
    n = 20000
    r0 = np.concatenate([
        rng.uniform(2.0, 12.0, n - 200),  # below, inside and beyond the grid
        grid[rng.integers(0, grid.size, 200)],  # exactly on grid points
    ])  # fmt: skip
    pf = 10 ** rng.uniform(-7, -3, n)
    reported = r0 * rng.uniform(0.2, 1.2, n)
    noise = rng.standard_normal(n) * 50  # large: both clip bounds are reached
    args = (r0, pf, reported, noise, grid, curvature, 4e-5, 2 * np.pi**2 / 0.6**2, 0.02, 0.3,
            1e-3)  # fmt: skip
    got_r, got_rho = echo_ranges(*args)
    want_r, want_rho = _numpy_reference(*args)
    assert np.array_equal(got_r.view(np.uint64), want_r.view(np.uint64))
    assert np.array_equal(got_rho.view(np.uint64), want_rho.view(np.uint64))
    assert (want_r == 1e-3).any() and (want_r == r0 + 0.3).any()


def test_target_returns_match_numpy_bit_for_bit():
    from lads.physics.fog_kernels import target_returns

    rng = np.random.default_rng(3)
    n, active = 5000, 4000
    idx = np.sort(rng.choice(n, active, replace=False))
    target = rng.random(active) < 0.7
    r0 = rng.uniform(0.5, 80.0, active)
    rho = rng.random(active)
    t2 = np.exp(-2 * 0.06 * r0)
    p_clear = rho / r0**2 + 1e-7
    p_target = p_clear * t2 * rng.uniform(0.5, 2.0, active)  # some above clear: no noise
    noise = rng.standard_normal(int(target.sum())) * 1e4  # large: the range floor is reached
    got_r, got_rho = target_returns(n, idx, target, r0, rho, t2, p_target, p_clear, noise,
                                    0.5 * 0.02**2 * 4e-5, 1e-3)  # fmt: skip
    # The rule as numpy expressions.
    extra_var = 0.5 * 0.02**2 * 4e-5 * (1.0 / p_target[target] - 1.0 / p_clear[target])
    want_r, want_rho = np.zeros(n), np.zeros(n)
    want_r[idx[target]] = np.maximum(r0[target] + np.sqrt(np.maximum(extra_var, 0.0)) * noise,
                                     1e-3)  # fmt: skip
    want_rho[idx[target]] = rho[target] * t2[target]
    assert np.array_equal(got_r.view(np.uint64), want_r.view(np.uint64))
    assert np.array_equal(got_rho.view(np.uint64), want_rho.view(np.uint64))
    assert (want_r[idx[target]] == 1e-3).any()
