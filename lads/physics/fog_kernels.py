"""Compiled per-beam loops of the fog model (numba, cached on disk).

Each operation repeats the numpy expression it replaces in the same order (np.interp's
formula included), and uses only IEEE-exact arithmetic (+, -, *, /, sqrt, min, max), so the
bytes are the numpy ones (numpy's error model too: x / 0 is inf, not an exception);
tests/unit/test_fog_kernels.py checks that against the numpy form of every rule, on every
branch. Randomness stays with the caller: standard normals are drawn
by its numpy Generator, in the order the docstrings give, and passed in.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

# Floor of the echo's relative curvature and cap of the pulse / echo curvature ratio.
KAPPA_FLOOR_PER_M2 = 1e-12
KAPPA_RATIO_CAP = 1e6
# Return modes, as `fog_choices` takes them.
MODE_CODES = {"strongest": 0, "last": 1, "dual": 2}
# Bits of a beam's choice: its target returns, its fog echo is the first return, its fog
# echo is the second return (behind a target that is both strongest and last).
TARGET, ECHO_FIRST, ECHO_SECOND = 1, 2, 4
_KEPT, _ATTENUATED, _PARTICLE, _LOST = np.uint8(0), np.uint8(1), np.uint8(2), np.uint8(3)


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _lerp(x: float, x0: float, x1: float, f0: float, f1: float) -> float:
    """np.interp's value at x in the cell [x0, x1) with values f0, f1: the same formula and
    NaN fallbacks (scalars only: array arguments would cost reference counting per call)."""
    if x0 == x:
        return f0
    slope = (f1 - f0) / (x1 - x0)
    out = slope * (x - x0) + f0
    if math.isnan(out):
        out = slope * (x - x1) + f1
        if math.isnan(out) and f0 == f1:
            out = f0
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def echo_lookup(
    r0_m: npt.NDArray[np.float64],
    grid_m: npt.NDArray[np.float64],
    peak_unit: npt.NDArray[np.float64],
    peak_range_m: npt.NDArray[np.float64],
    curvature_per_m2: npt.NDArray[np.float64],
    power_scale: float,
    overlap_start_m: float,
    report_shift_m: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The fog echo in front of each target at r0 (A,), from one table (`SoftReturnTable`).

    Returns:
        p_fog (A,): power_scale * peak_unit(r0), 0 where r0 < R1 (no fog in front), in
            reflectivity / m^2 (power_scale = pi beta_pi).
        reported_m (A,): peak_range(r0) - report_shift_m, the range the sensor reports.
        kappa_per_m2 (A,): max(curvature(r0), KAPPA_FLOOR_PER_M2), the echo's relative
            curvature.
    """
    m = r0_m.size
    p_fog = np.empty(m)
    reported = np.empty(m)
    kappa = np.empty(m)
    last = grid_m.size - 1
    for a in range(m):
        x = r0_m[a]
        if x >= grid_m[last]:  # np.interp's order: beyond the grid first, then before it
            unit, peak, curv = peak_unit[last], peak_range_m[last], curvature_per_m2[last]
        elif x < grid_m[0]:
            unit, peak, curv = peak_unit[0], peak_range_m[0], curvature_per_m2[0]
        else:
            lo, hi = 0, last  # grid_m[lo] <= x < grid_m[hi]
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if grid_m[mid] <= x:
                    lo = mid
                else:
                    hi = mid
            x0, x1 = grid_m[lo], grid_m[lo + 1]
            unit = _lerp(x, x0, x1, peak_unit[lo], peak_unit[lo + 1])
            peak = _lerp(x, x0, x1, peak_range_m[lo], peak_range_m[lo + 1])
            curv = _lerp(x, x0, x1, curvature_per_m2[lo], curvature_per_m2[lo + 1])
        p_fog[a] = 0.0 if x < overlap_start_m else power_scale * unit
        reported[a] = peak - report_shift_m
        kappa[a] = max(curv, KAPPA_FLOOR_PER_M2)
    return p_fog, reported, kappa


@numba.njit(cache=True, nogil=True, error_model="numpy")
def fog_choices(
    mode: int,
    target_ok: npt.NDArray[np.bool_],
    fog_ok: npt.NDArray[np.bool_],
    p_target: npt.NDArray[np.float64],
    p_fog: npt.NDArray[np.float64],
    r0_m: npt.NDArray[np.float64],
    reported_m: npt.NDArray[np.float64],
    pulse_length_m: float,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.int64]]:
    """Which returns each active beam gives (A,) and how many of each kind (3,).

    strongest: the echo if detected and P_f > P_w, else the target if detected. last: the
    target if detected, else the echo if detected. dual: the target if detected, and the echo
    first where it beats or replaces the target; where the target is both strongest and last,
    a detected echo a pulse length or more in front of it is the second return.

    Returns:
        choice (A,) uint8 of TARGET | ECHO_FIRST | ECHO_SECOND bits, and counts
        (targets, first echoes, second echoes).
    """
    m = r0_m.size
    choice = np.zeros(m, dtype=np.uint8)
    counts = np.zeros(3, dtype=np.int64)
    for a in range(m):
        stronger = p_fog[a] > p_target[a]
        if mode == 0:
            echo = fog_ok[a] and stronger
            target = target_ok[a] and not echo
        elif mode == 1:
            target = target_ok[a]
            echo = fog_ok[a] and not target
        else:
            target = target_ok[a]
            echo = fog_ok[a] and (stronger or not target)
        c = (TARGET if target else 0) | (ECHO_FIRST if echo else 0)
        if mode == 2 and target and not echo and fog_ok[a]:
            if reported_m[a] <= r0_m[a] - pulse_length_m:
                c |= ECHO_SECOND
                counts[2] += 1
        counts[0] += target
        counts[1] += echo
        choice[a] = c
    return choice, counts


@numba.njit(cache=True, nogil=True, error_model="numpy")
def fog_returns(
    n: int,
    idx: npt.NDArray[np.int64],
    choice: npt.NDArray[np.uint8],
    r0_m: npt.NDArray[np.float64],
    rho: npt.NDArray[np.float64],
    t2: npt.NDArray[np.float64],
    p_target: npt.NDArray[np.float64],
    p_clear: npt.NDArray[np.float64],
    p_fog: npt.NDArray[np.float64],
    reported_m: npt.NDArray[np.float64],
    kappa_per_m2: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_second: npt.NDArray[np.float64],
    constants: npt.NDArray[np.float64],
) -> tuple[
    npt.NDArray[np.uint8],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.uint8],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
]:
    """First and second returns of every beam (n,) from the choices of `fog_choices`.

    A returned target: range max(r0 + sqrt(max(c (1/P_w - 1/P_clear), 0)) e, min_range),
    c = dR^2 P_min / 2 (the SNR drop's extra range noise), reflectivity rho T^2. A fog echo:
    sigma = min(dR / sqrt(2 P_f / P_min) * min(kappa_pulse / kappa, cap), 1 / sqrt(kappa)),
    range clip(reported + sigma e, min_range, r0 + half pulse), reflectivity P_f r^2.

    Args:
        idx: (A,) rows of the active beams among the frame's n; the other (A,) arrays are
            per active beam.
        noise: standard normals, the targets' in beam order, then the first echoes'.
        noise_second: standard normals of the second echoes, in beam order.
        constants: (6,) c, P_min, kappa_pulse (1/m^2), dR (m), half pulse (m), min range (m).

    Returns:
        codes, range (m) and reflectivity of the first return, then of the second: KEPT for
        inactive beams, LOST where no return (second: LOST unless a beam has two).
    """
    noise_scale, p_min, kappa_pulse = constants[0], constants[1], constants[2]
    range_accuracy_m, half_pulse_m, min_range_m = constants[3], constants[4], constants[5]
    codes1 = np.full(n, _KEPT, dtype=np.uint8)
    range1 = np.zeros(n)
    refl1 = np.zeros(n)
    codes2 = np.full(n, _LOST, dtype=np.uint8)
    range2 = np.zeros(n)
    refl2 = np.zeros(n)
    k_target, k_echo, k_second = 0, 0, 0
    for a in range(choice.size):  # the first echoes' normals follow all the targets'
        if choice[a] & TARGET:
            k_echo += 1
    for a in range(r0_m.size):
        i, c = idx[a], choice[a]
        if c == 0:
            codes1[i] = _LOST
            continue
        t_range, t_refl, e_range, e_refl = 0.0, 0.0, 0.0, 0.0
        if c & TARGET:
            extra_var = noise_scale * (1.0 / p_target[a] - 1.0 / p_clear[a])
            t_range = max(r0_m[a] + math.sqrt(max(extra_var, 0.0)) * noise[k_target], min_range_m)
            t_refl = rho[a] * t2[a]
            k_target += 1
        if c & (ECHO_FIRST | ECHO_SECOND):
            kappa = kappa_per_m2[a]
            snr = p_fog[a] / p_min
            timing = (
                range_accuracy_m / math.sqrt(2.0 * snr) * min(kappa_pulse / kappa, KAPPA_RATIO_CAP)
            )
            sigma = min(timing, 1.0 / math.sqrt(kappa))
            e = noise[k_echo] if c & ECHO_FIRST else noise_second[k_second]
            e_range = min(max(reported_m[a] + sigma * e, min_range_m), r0_m[a] + half_pulse_m)
            e_refl = p_fog[a] * (e_range * e_range)
        if c & ECHO_FIRST:
            k_echo += 1
            codes1[i], range1[i], refl1[i] = _PARTICLE, e_range, e_refl
            if c & TARGET:
                codes2[i], range2[i], refl2[i] = _ATTENUATED, t_range, t_refl
            continue
        codes1[i], range1[i], refl1[i] = _ATTENUATED, t_range, t_refl
        if c & ECHO_SECOND:
            k_second += 1
            codes2[i], range2[i], refl2[i] = _PARTICLE, e_range, e_refl
    return codes1, range1, refl1, codes2, range2, refl2
