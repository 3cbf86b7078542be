"""Positions in a short sorted table for many values, one compiled pass (numba).

numpy's searchsorted over an unsorted array of a frame's ~120k values costs about a
millisecond for a 63-entry table; a per-value binary search in a compiled loop returns the
same positions several times faster. The same holds for a point's nearest channel by
elevation, where a slope against the midpoints' tangents replaces the arctangent.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt


@numba.njit(cache=True, nogil=True)
def _left_positions(
    table: npt.NDArray[np.float64], values: npt.NDArray[np.float64]
) -> npt.NDArray[np.int64]:
    out = np.empty(values.shape[0], dtype=np.int64)
    n = table.shape[0]
    for i in range(values.shape[0]):
        v = values[i]
        if v != v:  # NaN sorts after everything, as in numpy
            out[i] = n
            continue
        lo, hi = 0, n
        while lo < hi:
            mid = (lo + hi) >> 1
            if table[mid] < v:
                lo = mid + 1
            else:
                hi = mid
        out[i] = lo
    return out


# A point whose slope z / rho lies within this relative distance of a midpoint's tangent is
# decided by numpy's degrees(arctan2) instead: both roundings are ~1e-15 relative, so
# everywhere else the slope and the angle fall on the same side of every midpoint.
_SLOPE_GUARD = 1e-9


@numba.njit(cache=True, nogil=True, error_model="numpy")  # z / 0 gives inf or NaN
def _slope_positions(
    xyz: npt.NDArray[np.float64], tan_mid: npt.NDArray[np.float64]
) -> npt.NDArray[np.int64]:
    """Midpoints below each point's elevation, counted on the slope z / rho against the
    midpoints' (increasing) tangents; -1 where the slope is NaN or within the guard."""
    out = np.empty(xyz.shape[0], dtype=np.int64)
    n = tan_mid.shape[0]
    for i in range(xyz.shape[0]):
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        t = z / math.sqrt(x * x + y * y)  # +-inf straight up or down, NaN at the origin
        if t != t:
            out[i] = -1
            continue
        lo, hi = 0, n
        while lo < hi:
            mid = (lo + hi) >> 1
            if tan_mid[mid] < t:
                lo = mid + 1
            else:
                hi = mid
        unsure = False
        for j in (lo - 1, lo):
            if 0 <= j < n and abs(t - tan_mid[j]) <= _SLOPE_GUARD * (abs(t) + abs(tan_mid[j])):
                unsure = True
        out[i] = -1 if unsure else lo
    return out


def elevation_positions(
    xyz64: npt.NDArray[np.float64], midpoints_deg: npt.NDArray[np.float64]
) -> npt.NDArray[np.int64]:
    """`left_positions(midpoints_deg, degrees(arctan2(z, hypot(x, y))))` of (N, 3) float64
    points against increasing midpoints within (-90, 90) deg, the same (N,) int64 values:
    a compiled slope test decides all but the points within a rounding of a midpoint (or at
    the origin), which take numpy's angle. (Exactly on a midpoint numpy's angle itself may
    fall either side: np.degrees can differ in the last bit with the array's length.)"""
    xyz = np.ascontiguousarray(xyz64, dtype=np.float64)
    mids = np.asarray(midpoints_deg, dtype=np.float64)
    out = _slope_positions(xyz, np.tan(np.radians(mids)))
    unsure = np.flatnonzero(out < 0)
    if unsure.size:
        p = xyz[unsure]
        angle = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
        out[unsure] = left_positions(mids, angle)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def nearest_entry(table: npt.NDArray[np.float64], value: float) -> int:
    """Index of the entry of an increasing float64 table nearest to `value`, ties to the
    lower entry (the same comparisons in float64 wherever a nearest beam is looked up)."""
    last = table.shape[0] - 1
    if last <= 0:
        return 0
    right: int = min(max(int(np.searchsorted(table, value)), 1), last)
    left = right - 1
    return left if abs(value - table[left]) <= abs(table[right] - value) else right


def left_positions(table: npt.ArrayLike, values: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """`np.searchsorted(table, values)` (side "left": the number of entries below each
    value) for an increasing float64 table without NaN and any float values; int64 of
    the values' shape."""
    v = np.asarray(values, dtype=np.float64)
    t = np.ascontiguousarray(table, dtype=np.float64)
    return _left_positions(t, np.ascontiguousarray(v.reshape(-1))).reshape(v.shape)
