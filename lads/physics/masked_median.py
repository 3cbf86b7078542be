"""The median of the selected values of an array, in one compiled pass (numba).

`np.median(values[mask])` copies the selection and partitions the copy; on a frame's ~120k
incidence cosines that is about a millisecond of the learned intensity stage. Here a
histogram of the selected values finds the bucket(s) holding the middle rank(s), and only
their values are sorted. Bucketing is monotone in the value, so ranks are kept, and the
result is numpy's own: the middle value, or the two middle values' (a + b) / 2, which is
what numpy's mean of two float64 numbers computes; NaN if a selected value is NaN.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

BUCKETS = 4096  # a frame's values then leave a few dozen in the middle bucket


@numba.njit(cache=True, nogil=True)
def _span(values: npt.NDArray[np.float64], mask: npt.NDArray[np.bool_]) -> tuple[int, float, float]:
    """(count, min, max) of the selected values; count -1 if one of them is NaN."""
    n, lo, hi, nan = 0, np.inf, -np.inf, False
    for i in range(values.shape[0]):
        if mask[i]:
            v = values[i]
            n += 1
            lo = v if v < lo else lo
            hi = v if v > hi else hi
            nan |= v != v
    return (-1 if nan else n), lo, hi


@numba.njit(cache=True, nogil=True)
def _buckets(
    values: npt.NDArray[np.float64],
    mask: npt.NDArray[np.bool_],
    lo: float,
    scale: float,
    buckets: int,
) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int64]]:
    """Each value's bucket (-1 where not selected) and the selected values per bucket."""
    bucket = np.full(values.shape[0], -1, dtype=np.int32)
    counts = np.zeros(buckets, dtype=np.int64)
    for i in range(values.shape[0]):
        if mask[i]:
            b = int((values[i] - lo) * scale)
            bucket[i] = b
            counts[b] += 1
    return bucket, counts


@numba.njit(cache=True, nogil=True)
def _in_buckets(
    values: npt.NDArray[np.float64], bucket: npt.NDArray[np.int32], first: int, last: int, size: int
) -> npt.NDArray[np.float64]:
    """The values of buckets first..last, sorted."""
    picked = np.empty(size)
    k = 0
    for i in range(values.shape[0]):
        if first <= bucket[i] <= last:
            picked[k] = values[i]
            k += 1
    picked.sort()
    return picked


@numba.njit(cache=True, nogil=True)
def _median(values: npt.NDArray[np.float64], mask: npt.NDArray[np.bool_], buckets: int) -> float:
    n, lo, hi = _span(values, mask)
    if n <= 0:
        return np.nan
    if lo == hi or not (hi - lo < np.inf):
        return _sorted_middle(values, mask, lo, hi, n)
    scale = (buckets - 1) / (hi - lo)
    bucket, counts = _buckets(values, mask, lo, scale, buckets)
    first, second = (n - 1) // 2, n // 2  # the middle ranks (equal for odd n)
    below, b_first, b_second, seen = 0, -1, -1, 0
    for b in range(buckets):
        if b_first < 0 and seen + counts[b] > first:
            b_first, below = b, seen
        if seen + counts[b] > second:
            b_second = b
            break
        seen += counts[b]
    picked = _in_buckets(values, bucket, b_first, b_second, seen + counts[b_second] - below)
    a, c = picked[first - below], picked[second - below]
    return a if first == second else (a + c) / 2.0


@numba.njit(cache=True, nogil=True)
def _sorted_middle(
    values: npt.NDArray[np.float64], mask: npt.NDArray[np.bool_], lo: float, hi: float, n: int
) -> float:
    """All values equal (or a span too wide to bucket): sort the selection."""
    if lo == hi:
        return lo
    picked = np.empty(n)
    k = 0
    for i in range(values.shape[0]):
        if mask[i]:
            picked[k] = values[i]
            k += 1
    picked.sort()
    first, second = (n - 1) // 2, n // 2
    return picked[first] if first == second else (picked[first] + picked[second]) / 2.0


def masked_median(values: npt.ArrayLike, mask: npt.ArrayLike) -> float:
    """`float(np.median(values[mask]))` for (N,) values and an (N,) bool mask, bit for bit;
    NaN for an empty selection (numpy warns and returns NaN there)."""
    v = np.ascontiguousarray(values, dtype=np.float64)
    m = np.ascontiguousarray(mask, dtype=np.bool_)
    return float(_median(v, m, BUCKETS))
