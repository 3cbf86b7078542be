"""Compiled per-beam loops for the weather models (numba, cached on disk).

Only loops whose numpy form allocates several (N,)-sized temporaries per frame live here;
randomness never does: uniforms are drawn by the caller's numpy Generator and passed in,
so output bytes depend only on the generator state, not on numba.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

_KEPT, _ATTENUATED, _PARTICLE, _LOST = np.uint8(0), np.uint8(1), np.uint8(2), np.uint8(3)


@numba.njit(cache=True, nogil=True)
def survivors(
    xyz: npt.NDArray[np.float32],
    range_old_m: npt.NDArray[np.float64],
    intensity: npt.NDArray[np.float32],
    scale: np.float32,
    levels: npt.NDArray[np.float32],
    codes1: npt.NDArray[np.uint8],
    range1_m: npt.NDArray[np.float64],
    refl1: npt.NDArray[np.float64],
    codes2: npt.NDArray[np.uint8],
    range2_m: npt.NDArray[np.float64],
    refl2: npt.NDArray[np.float64],
) -> tuple[
    npt.NDArray[np.int64], npt.NDArray[np.uint8], npt.NDArray[np.float32], npt.NDArray[np.float32]
]:
    """The output points of up to two returns per beam, in beam order, first return first.

    A return whose code is LOST gives no point. KEPT keeps the input xyz and intensity bytes;
    any other outcome is moved along the ray to its new range (unless unchanged) and its
    reflectivity encoded as `IntensityEncoding.from_reflectivity` does (the same float32
    steps: levels[clip(rint(float32(rho) * scale))]). The body is written out once, not
    split into helper calls: numba's per-call array reference counting made those 4x slower.

    Args:
        xyz: (N, 3) float32 input points, m; range_old_m: (N,) float64, m; intensity: (N,)
            float32 input intensities; scale, levels: `IntensityEncoding.compiled`.
        codes1, range1_m, refl1: (N,) the first return's Outcome (uint8), new range (m) and
            reflectivity (float64); codes2, range2_m, refl2 the second's (all LOST: one
            return per beam).

    Returns:
        source (M,) int64 non-decreasing, outcome (M,) uint8, out_xyz (M, 3) float32 and
        out_intensity (M,) float32.
    """
    n = range_old_m.size
    m = 0
    for i in range(n):
        m += (codes1[i] != _LOST) + (codes2[i] != _LOST)
    source = np.empty(m, dtype=np.int64)
    outcome = np.empty(m, dtype=np.uint8)
    out_xyz = np.empty((m, 3), dtype=np.float32)
    out_intensity = np.empty(m, dtype=np.float32)
    top = np.float32(levels.size - 1)
    j = 0
    for i in range(n):
        for k in range(2):
            code = codes1[i] if k == 0 else codes2[i]
            if code == _LOST:
                continue
            r_new = range1_m[i] if k == 0 else range2_m[i]
            source[j], outcome[j] = i, code
            if code != _KEPT and r_new != range_old_m[i]:
                ratio = r_new / range_old_m[i]
                for c in range(3):
                    out_xyz[j, c] = np.float32(xyz[i, c] * ratio)
            else:
                for c in range(3):
                    out_xyz[j, c] = xyz[i, c]
            if code == _KEPT:
                out_intensity[j] = intensity[i]
            else:
                steps = np.rint(np.float32(refl1[i] if k == 0 else refl2[i]) * scale)
                if not steps > 0:
                    steps = np.float32(0.0)
                elif steps > top:
                    steps = top
                out_intensity[j] = levels[int(steps)]
            j += 1
    return source, outcome, out_xyz, out_intensity


# Above this mean the inversion's exp(-mu) loses all precision; the caller redraws.
MAX_INVERSION_MEAN = 30.0


@numba.njit(cache=True, nogil=True)
def poisson_counts_from_table(
    cumulative: npt.NDArray[np.float64],
    r_grid_m: npt.NDArray[np.float64],
    cell_lookup: npt.NDArray[np.int64],
    lookup_step_m: float,
    column: npt.NDArray[np.int64],
    r0_m: npt.NDArray[np.float64],
    uniform: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Per beam: mean number of proposals mu(r0; s_column) and a Poisson draw of it.

    mu is the tabulated cumulative count, linear in range between rows (0 before the first
    row); the count inverts the Poisson CDF at `uniform` (exact; almost every mean is tiny,
    so the loop rarely runs more than once). Means above MAX_INVERSION_MEAN get count -1:
    the caller draws those with another sampler.

    Args:
        cumulative: (Q, R) float64 table, row k = mu(r; s_k) at ranges r_grid_m.
        r_grid_m: (R,) float64 increasing ranges, m.
        cell_lookup: (L,) int64, the cell j (r_grid_m[j] <= r < r_grid_m[j + 1]) holding
            r = r_grid_m[0] + k * lookup_step_m, covering the whole grid.
        column: (N,) int64 row per beam.
        r0_m: (N,) float64 search range per beam, m (<= the last grid range).
        uniform: (N,) float64 U(0, 1) draws.

    Returns:
        mean (N,) float64, count (N,) int64.
    """
    n = r0_m.size
    n_r = cumulative.shape[1]
    mean = np.empty(n)
    count = np.zeros(n, dtype=np.int64)
    for i in range(n):
        r0 = r0_m[i]
        if r0 <= r_grid_m[0]:
            mean[i] = 0.0
            continue
        k_probe = min(int((r0 - r_grid_m[0]) / lookup_step_m), cell_lookup.size - 1)
        j = cell_lookup[k_probe]
        while j < n_r - 2 and r0 > r_grid_m[j + 1]:
            j += 1
        frac = min(max((r0 - r_grid_m[j]) / (r_grid_m[j + 1] - r_grid_m[j]), 0.0), 1.0)
        k = column[i]
        mu = cumulative[k, j] * (1.0 - frac) + cumulative[k, j + 1] * frac
        mean[i] = mu
        if mu > MAX_INVERSION_MEAN:
            count[i] = -1
            continue
        prob = math.exp(-mu)
        cdf = prob
        c = 0
        u = uniform[i]
        # Stop where the pmf underflows: the remaining mass is below double precision.
        while u > cdf and prob > 0.0:
            c += 1
            prob *= mu / c
            cdf += prob
        count[i] = c
    return mean, count


# Survival states of `survival_screen`.
SURE = np.uint8(0)  # q = 1 exactly: no draw
APPROX = np.uint8(1)  # q < 1 for certain; q_approx is within the caller's tolerance of q
EXACT = np.uint8(2)  # too close to 1 (or z < 0): the caller computes q exactly
INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
# Phi values this far apart stay apart in float64 (its rounding near 1 is ~1e-16).
DISTINCT_PHI_GAP = 1e-13


@numba.njit(cache=True, nogil=True)
def survival_screen(
    z: npt.NDArray[np.float64],
    z_weather: npt.NDArray[np.float64],
    active: npt.NDArray[np.bool_],
    phi_table: npt.NDArray[np.float64],
    z_start: float,
    steps_per_unit: float,
    certain_z: float,
    tolerance: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]:
    """Survival q = Phi(z_w) / Phi(z) approximated from a table of Phi, and its state.

    `lads.physics.detection.target_survival` is exact; this screen lets the caller skip its
    two special-function calls wherever the table's answer is close enough to decide a draw.
    Phi is linear between table rows (z_start + k / steps_per_unit); below z_start it is 0.

    Args:
        z, z_weather: (N,) float64 clear-air and weather z-scores of each beam.
        active: (N,) bool beams the weather acts on.
        phi_table: (K,) float64 Phi at the rows, reaching past certain_z.
        tolerance: the bound the caller guarantees on |q_approx - q|.

    Returns:
        q_approx (N,) float64 (1.0 where SURE, unset where EXACT) and state (N,) uint8:
        SURE (inactive, z not finite or z_weather >= certain_z, as the exact rule), APPROX
        (z >= 0 and q < 1 for certain: q_approx + tolerance < 1, or the two Phi values too
        far apart to round to the same float) or EXACT.
    """
    n = z.size
    q = np.ones(n)
    state = np.zeros(n, dtype=np.uint8)
    for i in range(n):
        zc, zw = z[i], z_weather[i]
        if not active[i] or not math.isfinite(zc) or not zw < certain_z:
            continue
        if zc < 0.0:
            state[i] = EXACT
            continue
        num = 0.0
        if zw > z_start:
            pos = (zw - z_start) * steps_per_unit
            k = int(pos)
            num = phi_table[k] + (pos - k) * (phi_table[k + 1] - phi_table[k])
        den = 1.0
        if zc < certain_z:
            pos = (zc - z_start) * steps_per_unit
            k = int(pos)
            den = phi_table[k] + (pos - k) * (phi_table[k + 1] - phi_table[k])
        q[i] = num / den
        if q[i] + tolerance < 1.0:
            state[i] = APPROX
            continue
        # Near 1, q < 1 holds exactly when Phi(z_w) < Phi(min(z, certain_z)) by more than the
        # special function's rounding. Two lower bounds of that gap: phi's minimum times the
        # interval, and (for z_w > 0) Mills' ratio bounds x phi(x) / (x^2 + 1) <= 1 - Phi(x)
        # <= phi(x) / x.
        top = min(zc, certain_z)
        phi_top = math.exp(-0.5 * top * top) * INV_SQRT_2PI
        phi_w = math.exp(-0.5 * zw * zw) * INV_SQRT_2PI
        gap = (top - zw) * min(phi_top, phi_w)
        if zw > 0.0:
            gap = max(gap, phi_w * zw / (zw * zw + 1.0) - phi_top / top)
        state[i] = APPROX if gap > DISTINCT_PHI_GAP else EXACT
    return q, state


@numba.njit(cache=True, nogil=True)
def dual_particle_returns(
    active: npt.NDArray[np.bool_],
    detected: npt.NDArray[np.bool_],
    target_power: npt.NDArray[np.float64],
    target_range_m: npt.NDArray[np.float64],
    target_refl: npt.NDArray[np.float64],
    strongest_range_m: npt.NDArray[np.float64],
    strongest_power: npt.NDArray[np.float64],
    has_strongest: npt.NDArray[np.bool_],
    last_range_m: npt.NDArray[np.float64],
    last_power: npt.NDArray[np.float64],
    has_last: npt.NDArray[np.bool_],
) -> tuple[
    npt.NDArray[np.uint8],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.uint8],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
]:
    """First and second returns (n,) of a dual-return rain or snow frame
    (`lads.physics.particles._dual`: the rule is stated there).

    Args:
        active, detected: (n,) beams the weather acts on, targets still detected.
        target_power, target_range_m, target_refl: (n,) each target's weather power, range
            (m) and reflectivity.
        strongest_*, last_*, has_*: (n,) range (m) and power of each beam's strongest and of
            its farthest detectable particle, and whether it has one.

    Returns:
        codes, range (m) and reflectivity of the first return, then of the second.
    """
    n = active.size
    codes1 = np.full(n, _KEPT, dtype=np.uint8)
    range1 = np.empty(n)
    refl1 = np.empty(n)
    codes2 = np.full(n, _LOST, dtype=np.uint8)
    range2 = np.empty(n)
    refl2 = np.empty(n)
    for i in range(n):
        s_r, s_p, has_s = strongest_range_m[i], strongest_power[i], has_strongest[i]
        l_r, l_p, has_l = last_range_m[i], last_power[i], has_last[i]
        t_r, t_refl = target_range_m[i], target_refl[i]
        first_particle = has_s and active[i] and (not detected[i] or s_p > target_power[i])
        if first_particle:
            codes1[i], range1[i], refl1[i] = _PARTICLE, s_r, s_p * (s_r * s_r)
        else:
            codes1[i] = _ATTENUATED if detected[i] else (_LOST if active[i] else _KEPT)
            range1[i], refl1[i] = t_r, t_refl
        range2[i], refl2[i] = t_r, t_refl
        if first_particle and detected[i]:
            codes2[i] = _ATTENUATED
        elif first_particle and has_l and l_r != s_r:
            codes2[i], range2[i], refl2[i] = _PARTICLE, l_r, l_p * (l_r * l_r)
        elif not first_particle and detected[i] and has_s:
            codes2[i], range2[i], refl2[i] = _PARTICLE, s_r, s_p * (s_r * s_r)
    return codes1, range1, refl1, codes2, range2, refl2
