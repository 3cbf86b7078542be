"""The compiled fog loops give the bytes of the numpy rule they replace, on every branch."""

from __future__ import annotations

import numpy as np
import pytest

from lads.physics.fog_kernels import (
    KAPPA_FLOOR_PER_M2,
    KAPPA_RATIO_CAP,
    MODE_CODES,
    echo_lookup,
    fog_choices,
    fog_returns,
)
from lads.physics.result import Outcome

DR, P_MIN, LENGTH, MIN_RANGE = 0.02, 4e-5, 1.2, 1e-3


def _numpy_rule(
    mode,
    n,
    idx,
    r0,
    rho,
    t2,
    p_target,
    p_clear,
    target_ok,
    fog_ok,
    grid,
    unit,
    peak_range,
    curvature,
    scale,
    r1,
    shift,
    noise,
    noise_second,
):
    """The fog returns as numpy expressions (docs/physics.md §7): which returns each beam
    gives, the targets' SNR range noise and rho T^2, the echoes' timing noise and P_f r^2."""
    p_fog = scale * np.interp(r0, grid, unit)
    p_fog[r0 < r1] = 0.0
    reported = np.interp(r0, grid, peak_range) - shift
    kappa = np.maximum(np.interp(r0, grid, curvature), KAPPA_FLOOR_PER_M2)
    stronger = p_fog > p_target
    if mode == "strongest":
        fog = fog_ok & stronger
        target = target_ok & ~fog
    elif mode == "last":
        target, fog = target_ok, fog_ok & ~target_ok
    else:
        target, fog = target_ok, fog_ok & (stronger | ~target_ok)
    second_echo = target & ~fog & fog_ok & (reported <= r0 - LENGTH) & (mode == "dual")
    k = int(target.sum())

    def echo(mask, e):
        with np.errstate(divide="ignore"):  # P_f = 0 (no fog in front): timing is inf
            timing = (
                DR
                / np.sqrt(2.0 * (p_fog[mask] / P_MIN))
                * np.minimum(2 * np.pi**2 / LENGTH**2 / kappa[mask], KAPPA_RATIO_CAP)
            )
        sigma = np.minimum(timing, 1.0 / np.sqrt(kappa[mask]))
        out = np.clip(reported[mask] + sigma * e, MIN_RANGE, r0[mask] + 0.5 * LENGTH)
        return out, p_fog[mask] * out**2

    extra_var = 0.5 * DR**2 * P_MIN * (1.0 / p_target[target] - 1.0 / p_clear[target])
    t_range = np.zeros(n)
    t_refl = np.zeros(n)
    t_range[idx[target]] = np.maximum(
        r0[target] + np.sqrt(np.maximum(extra_var, 0.0)) * noise[:k], MIN_RANGE
    )
    t_refl[idx[target]] = rho[target] * t2[target]
    range1, refl1 = t_range.copy(), t_refl.copy()
    range1[idx[fog]], refl1[idx[fog]] = echo(fog, noise[k:])
    codes1 = np.full(n, Outcome.KEPT, dtype=np.uint8)
    codes1[idx[target]] = Outcome.ATTENUATED
    codes1[idx[fog]] = Outcome.PARTICLE
    codes1[idx[~target & ~fog]] = Outcome.LOST
    t_range[idx[second_echo]], t_refl[idx[second_echo]] = echo(second_echo, noise_second)
    codes2 = np.full(n, Outcome.LOST, dtype=np.uint8)
    codes2[idx[fog & target]] = Outcome.ATTENUATED
    codes2[idx[second_echo]] = Outcome.PARTICLE
    # Returns the compiled path leaves unset (LOST) are not compared.
    return (codes1, range1, refl1, codes2, t_range, t_refl), (
        k,
        int(fog.sum()),
        int(second_echo.sum()),
    )


@pytest.mark.parametrize("mode", ["strongest", "last", "dual"])
def test_fog_loops_match_the_numpy_rule_bit_for_bit(mode):
    rng = np.random.default_rng(11)
    n, active = 30_000, 26_000
    idx = np.sort(rng.choice(n, active, replace=False))
    grid = np.linspace(3.25, 8.5, 526)
    unit = rng.uniform(0.0, 2e-3, grid.size)
    peak_range = grid * rng.uniform(0.3, 1.2, grid.size)
    curvature = rng.uniform(0.0, 40.0, grid.size)
    curvature[:3] = 0.0  # the curvature floor
    curvature[10:12] = 1e-9  # the ratio cap
    r0 = np.concatenate(
        [
            rng.uniform(0.5, 12.0, active - 300),  # below, inside and beyond the table
            grid[rng.integers(0, grid.size, 300)],  # exactly on grid points
        ]
    )
    rho = rng.random(active)
    t2 = np.exp(-2 * 0.06 * r0)
    p_clear = rho / r0**2 + 1e-7
    p_target = p_clear * t2 * rng.uniform(0.5, 2.0, active)  # some above clear: no noise
    target_ok, fog_ok = rng.random(active) < 0.7, rng.random(active) < 0.6
    scale, r1, shift = 0.3, 3.25, 0.5 * LENGTH
    p_fog, reported, kappa = echo_lookup(r0, grid, unit, peak_range, curvature, scale, r1, shift)
    choice, counts = fog_choices(
        MODE_CODES[mode], target_ok, fog_ok, p_target, p_fog, r0, reported, LENGTH
    )
    noise = rng.standard_normal(int(counts[0] + counts[1])) * 50  # both clip bounds reached
    noise_second = rng.standard_normal(int(counts[2])) * 50
    constants = np.array(
        [0.5 * DR**2 * P_MIN, P_MIN, 2 * np.pi**2 / LENGTH**2, DR, 0.5 * LENGTH, MIN_RANGE]
    )
    got = fog_returns(
        n,
        idx,
        choice,
        r0,
        rho,
        t2,
        p_target,
        p_clear,
        p_fog,
        reported,
        kappa,
        noise,
        noise_second,
        constants,
    )
    want, want_counts = _numpy_rule(
        mode,
        n,
        idx,
        r0,
        rho,
        t2,
        p_target,
        p_clear,
        target_ok,
        fog_ok,
        grid,
        unit,
        peak_range,
        curvature,
        scale,
        r1,
        shift,
        noise,
        noise_second,
    )
    assert tuple(counts) == want_counts
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[3], want[3])
    for codes, values, expected in ((got[0], got[1:3], want[1:3]), (got[3], got[4:6], want[4:6])):
        shown = codes != Outcome.LOST
        for g, w in zip(values, expected, strict=True):
            assert np.array_equal(g[shown].view(np.uint64), w[shown].view(np.uint64))
    if mode == "dual":
        both = (got[0] == Outcome.PARTICLE) & (got[3] == Outcome.ATTENUATED)
        assert counts[2] > 0 and both.any()
    ranges = got[1][got[0] == Outcome.PARTICLE]
    assert (ranges == MIN_RANGE).any()


def test_the_table_lookup_is_numpy_interp_on_a_table_with_flat_and_nan_free_cells():
    grid = np.array([1.0, 2.0, 3.0, 4.0])
    values = np.array([0.0, 1e-300, 1e300, 1e300])  # steep, tiny and flat cells
    x = np.array([0.5, 1.0, 1.5, 2.0, 2.5, 3.5, 4.0, 9.0])
    p_fog, reported, kappa = echo_lookup(x, grid, values, values, values, 1.0, 0.0, 0.0)
    want = np.interp(x, grid, values)
    assert np.array_equal(p_fog.view(np.uint64), want.view(np.uint64))
    assert np.array_equal(reported.view(np.uint64), want.view(np.uint64))
    np.testing.assert_array_equal(kappa, np.maximum(want, KAPPA_FLOOR_PER_M2))
