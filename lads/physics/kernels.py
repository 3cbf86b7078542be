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

_LOST = np.uint8(3)
_KEPT = np.uint8(0)


@numba.njit(cache=True, nogil=True, inline="always")
def _encode(reflectivity: float, scale: np.float32, levels: npt.NDArray[np.float32]) -> np.float32:
    """`IntensityEncoding.from_reflectivity` of one value, the same float32 steps."""
    steps = np.rint(np.float32(reflectivity) * scale)
    if not steps > 0:
        steps = np.float32(0.0)
    elif steps > levels.size - 1:
        steps = np.float32(levels.size - 1)
    return levels[int(steps)]


@numba.njit(cache=True, nogil=True, inline="always")
def _put(  # type: ignore[no-untyped-def]
    j,
    i,
    code,
    range_new_m,
    reflectivity,
    xyz,
    range_old_m,
    intensity,
    scale,
    levels,
    source,
    outcome,
    out_xyz,
    out_intensity,
):
    """Output point j from beam i's return: KEPT keeps the input bytes; any other outcome is
    moved along the ray to range_new_m (unless unchanged) and its reflectivity encoded."""
    source[j], outcome[j] = i, code
    if code != _KEPT and range_new_m != range_old_m[i]:
        ratio = range_new_m / range_old_m[i]
        for c in range(3):
            out_xyz[j, c] = np.float32(xyz[i, c] * ratio)
    else:
        for c in range(3):
            out_xyz[j, c] = xyz[i, c]
    out_intensity[j] = intensity[i] if code == _KEPT else _encode(reflectivity, scale, levels)


@numba.njit(cache=True, nogil=True)
def scaled_survivors(
    xyz: npt.NDArray[np.float32],
    range_old_m: npt.NDArray[np.float64],
    intensity: npt.NDArray[np.float32],
    encoding: tuple[np.float32, npt.NDArray[np.float32]],
    codes: npt.NDArray[np.uint8],
    range_new_m: npt.NDArray[np.float64],
    reflectivity: npt.NDArray[np.float64],
) -> tuple[
    npt.NDArray[np.int64], npt.NDArray[np.uint8], npt.NDArray[np.float32], npt.NDArray[np.float32]
]:
    """Non-LOST beams with their output xyz, moved along the ray to the new range, and
    intensity. KEPT beams and beams whose range did not change keep their input xyz bytes;
    KEPT beams keep their intensity, the others get their reflectivity encoded.

    Args:
        xyz: (N, 3) float32 input points, m; range_old_m: (N,) float64, m; intensity: (N,)
            float32 input intensities; encoding: `IntensityEncoding.compiled` (scale, levels).
        codes: (N,) uint8 Outcome codes; range_new_m: (N,) float64, m; reflectivity: (N,)
            float64 reflectivity of each return.

    Returns:
        source (M,) int64 ascending, outcome (M,) uint8, out_xyz (M, 3) float32 and
        out_intensity (M,) float32.
    """
    scale, levels = encoding
    n = codes.size
    m = 0
    for i in range(n):
        m += codes[i] != _LOST
    source = np.empty(m, dtype=np.int64)
    outcome = np.empty(m, dtype=np.uint8)
    out_xyz = np.empty((m, 3), dtype=np.float32)
    out_intensity = np.empty(m, dtype=np.float32)
    j = 0
    for i in range(n):
        if codes[i] != _LOST:
            _put(j, i, codes[i], range_new_m[i], reflectivity[i], xyz, range_old_m, intensity,
                 scale, levels, source, outcome, out_xyz, out_intensity)  # fmt: skip
            j += 1
    return source, outcome, out_xyz, out_intensity


@numba.njit(cache=True, nogil=True)
def dual_survivors(
    xyz: npt.NDArray[np.float32],
    range_old_m: npt.NDArray[np.float64],
    intensity: npt.NDArray[np.float32],
    encoding: tuple[np.float32, npt.NDArray[np.float32]],
    codes1: npt.NDArray[np.uint8],
    range1_m: npt.NDArray[np.float64],
    refl1: npt.NDArray[np.float64],
    codes2: npt.NDArray[np.uint8],
    range2_m: npt.NDArray[np.float64],
    refl2: npt.NDArray[np.float64],
) -> tuple[
    npt.NDArray[np.int64], npt.NDArray[np.uint8], npt.NDArray[np.float32], npt.NDArray[np.float32]
]:
    """`scaled_survivors` for two returns per beam in one pass: each beam's first return
    (if not LOST), then its second (if not LOST), in beam order; source non-decreasing.

    Args:
        codes1, range1_m, refl1: (N,) the first return's Outcome (uint8), new range (m) and
            reflectivity (float64); codes2, range2_m, refl2 the second's.
    """
    scale, levels = encoding
    n = range_old_m.size
    m = 0
    for i in range(n):
        m += (codes1[i] != _LOST) + (codes2[i] != _LOST)
    source = np.empty(m, dtype=np.int64)
    outcome = np.empty(m, dtype=np.uint8)
    out_xyz = np.empty((m, 3), dtype=np.float32)
    out_intensity = np.empty(m, dtype=np.float32)
    j = 0
    for i in range(n):
        if codes1[i] != _LOST:
            _put(j, i, codes1[i], range1_m[i], refl1[i], xyz, range_old_m, intensity, scale,
                 levels, source, outcome, out_xyz, out_intensity)  # fmt: skip
            j += 1
        if codes2[i] != _LOST:
            _put(j, i, codes2[i], range2_m[i], refl2[i], xyz, range_old_m, intensity, scale,
                 levels, source, outcome, out_xyz, out_intensity)  # fmt: skip
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
