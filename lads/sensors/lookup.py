"""Positions in a short sorted table for many values, one compiled pass (numba).

numpy's searchsorted over an unsorted array of a frame's ~120k values costs about a
millisecond for a 63-entry table; a per-value binary search in a compiled loop returns the
same positions several times faster.
"""

from __future__ import annotations

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
