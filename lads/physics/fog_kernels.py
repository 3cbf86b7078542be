"""Compiled per-echo loop of the fog model (numba, cached on disk).

Each operation repeats the numpy expression it replaces in the same order (np.interp's
formula included), and uses only IEEE-exact arithmetic (+, -, *, /, sqrt, min, max), so the
bytes are the numpy ones; tests/unit/test_fog_kernels.py checks that on every branch.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

# Floor of the echo's relative curvature and cap of the pulse / echo curvature ratio.
KAPPA_FLOOR_PER_M2 = 1e-12
KAPPA_RATIO_CAP = 1e6


@numba.njit(cache=True, nogil=True, inline="always")
def _interp(x: float, xp: npt.NDArray[np.float64], fp: npt.NDArray[np.float64]) -> float:
    """np.interp(x, xp, fp) for one finite x: the same cell, the same formula."""
    n = xp.size
    if x < xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    lo, hi = 0, n - 1  # xp[lo] <= x < xp[hi]
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if xp[mid] <= x:
            lo = mid
        else:
            hi = mid
    if xp[lo] == x:
        return fp[lo]
    slope = (fp[lo + 1] - fp[lo]) / (xp[lo + 1] - xp[lo])
    out = slope * (x - xp[lo]) + fp[lo]
    if math.isnan(out):
        out = slope * (x - xp[lo + 1]) + fp[lo + 1]
        if math.isnan(out) and fp[lo] == fp[lo + 1]:
            out = fp[lo]
    return out


@numba.njit(cache=True, nogil=True)
def echo_ranges(
    r0_m: npt.NDArray[np.float64],
    p_fog: npt.NDArray[np.float64],
    reported_m: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    grid_m: npt.NDArray[np.float64],
    curvature_per_m2: npt.NDArray[np.float64],
    p_min: float,
    kappa_pulse_per_m2: float,
    range_accuracy_m: float,
    half_pulse_m: float,
    min_range_m: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Reported range (m) and reflectivity P_f r^2 of fog echoes (M,), `fog._echo_returns`.

    sigma = min(dR / sqrt(2 P_f / P_min) * min(kappa_pulse / kappa, cap), 1 / sqrt(kappa)),
    kappa = max(curvature(r0), floor); range = clip(reported + sigma noise, min_range,
    r0 + half pulse).
    """
    m = r0_m.size
    out_r = np.empty(m)
    out_rho = np.empty(m)
    for i in range(m):
        kappa = max(_interp(r0_m[i], grid_m, curvature_per_m2), KAPPA_FLOOR_PER_M2)
        snr = p_fog[i] / p_min
        timing = range_accuracy_m / math.sqrt(2.0 * snr) * min(kappa_pulse_per_m2 / kappa,
                                                              KAPPA_RATIO_CAP)  # fmt: skip
        sigma = min(timing, 1.0 / math.sqrt(kappa))
        r = min(max(reported_m[i] + sigma * noise[i], min_range_m), r0_m[i] + half_pulse_m)
        out_r[i] = r
        out_rho[i] = p_fog[i] * (r * r)
    return out_r, out_rho


@numba.njit(cache=True, nogil=True)
def target_returns(
    n: int,
    idx: npt.NDArray[np.int64],
    target: npt.NDArray[np.bool_],
    r0_m: npt.NDArray[np.float64],
    rho: npt.NDArray[np.float64],
    t2: npt.NDArray[np.float64],
    p_target: npt.NDArray[np.float64],
    p_clear: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_scale: float,
    min_range_m: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(n,) range (m) and reflectivity of the returned targets, `fog._target_returns`.

    Per active beam a (rows idx of the frame's n beams) whose target returns, in order, with
    the next standard normal: range max(r0 + sqrt(max(c (1/P_w - 1/P_clear), 0)) noise,
    min_range), c = noise_scale = dR^2 P_min / 2; reflectivity rho T^2. Zeros elsewhere.
    """
    out_r = np.zeros(n)
    out_rho = np.zeros(n)
    k = 0
    for a in range(idx.size):
        if not target[a]:
            continue
        extra_var = noise_scale * (1.0 / p_target[a] - 1.0 / p_clear[a])
        r = r0_m[a] + math.sqrt(max(extra_var, 0.0)) * noise[k]
        k += 1
        out_r[idx[a]] = max(r, min_range_m)
        out_rho[idx[a]] = rho[a] * t2[a]
    return out_r, out_rho
