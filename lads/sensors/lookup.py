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


@numba.njit(cache=True, nogil=True, inline="always")
def _bisect_left(table: npt.NDArray[np.float64], v: float) -> int:
    """The number of entries of the increasing table below v (v not NaN)."""
    lo, hi = 0, table.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if table[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True, nogil=True)
def _left_positions(
    table: npt.NDArray[np.float64], values: npt.NDArray[np.float64]
) -> npt.NDArray[np.int64]:
    out = np.empty(values.shape[0], dtype=np.int64)
    for i in range(values.shape[0]):
        v = values[i]
        # NaN sorts after everything, as in numpy
        out[i] = table.shape[0] if v != v else _bisect_left(table, v)
    return out


# A point whose slope z / rho lies within this relative distance of a midpoint's tangent is
# decided by its angle instead: both roundings are ~1e-15 relative, so everywhere else the
# slope and the angle fall on the same side of every midpoint.
_SLOPE_GUARD = 1e-9


@numba.njit(cache=True, nogil=True, error_model="numpy")  # z / 0 gives inf or NaN
def _elevation_positions(
    xyz: npt.NDArray[np.float64],
    mid_deg: npt.NDArray[np.float64],
    tan_mid: npt.NDArray[np.float64],
) -> npt.NDArray[np.int64]:
    """Midpoints below each point's elevation: counted on the slope z / rho against the
    midpoints' (increasing) tangents, or on the angle in degrees where the slope is NaN or
    within the guard of a tangent."""
    out = np.empty(xyz.shape[0], dtype=np.int64)
    n = tan_mid.shape[0]
    for i in range(xyz.shape[0]):
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        t = z / math.sqrt(x * x + y * y)  # +-inf straight up or down, NaN at the origin
        lo = _bisect_left(tan_mid, t) if t == t else 0
        unsure = t != t
        for j in (lo - 1, lo):
            if 0 <= j < n and abs(t - tan_mid[j]) <= _SLOPE_GUARD * (abs(t) + abs(tan_mid[j])):
                unsure = True
        if unsure:  # atan2(0, 0) = 0 at the origin; a NaN angle sorts last, as in numpy
            angle = math.degrees(math.atan2(z, math.hypot(x, y)))
            lo = _bisect_left(mid_deg, angle) if angle == angle else n
        out[i] = lo
    return out


def elevation_positions(
    xyz64: npt.NDArray[np.float64], midpoints_deg: npt.NDArray[np.float64]
) -> npt.NDArray[np.int64]:
    """(N,) int64: the midpoints below each point's elevation, atan2(z, hypot(x, y)) in
    degrees, for (N, 3) float64 points and increasing midpoints within (-90, 90) deg (a
    point's nearest channel). A compiled slope test decides all but the points within a
    rounding of a midpoint (or at the origin), which take the angle itself; the same as
    numpy's degrees(arctan2) counted by searchsorted, but at a tie within the last bit, where
    numpy's vectorised arctangent itself varies with the arrays' memory layout."""
    xyz = np.ascontiguousarray(xyz64, dtype=np.float64)
    mids = np.ascontiguousarray(midpoints_deg, dtype=np.float64)
    return _elevation_positions(xyz, mids, np.tan(np.radians(mids)))


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
