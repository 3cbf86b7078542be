"""The direction grid of a scan seen from the origin, for `lads.physics.sphere_knn` (numba).

A spinning LiDAR's points are dense in direction and sparse in range, so they are binned by
direction into ELEVATION_BINS rows (over the scan's own elevation span; a row holds about
one ring of a 64-beam scan) by AZIMUTH_BINS columns, row-major, in CSR order by one stable
counting sort. Both angles are replaced by stand-ins that need no transcendental call and
are strictly increasing in them, with slopes within [1/2, 1] (so rounding in a stand-in is
rounding of the angle):

- elevation: t = z / (rho + |z|) in [-1, 1] (rho: horizontal range), whose edge t has the
  exact (rho, z) direction (1 - |t|, t);
- azimuth: the "diamond angle" |y| / (|x| + |y|), unfolded over the four quadrants into
  [0, 4], whose edge at quadrant q plus f has the exact (x, y) direction (1 - f, f) turned
  by q right angles.

Points at the origin (x = y = z = 0) have no direction and are kept apart.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

AZIMUTH_BINS = 1024  # a multiple of 4: one unit of the azimuth stand-in per quadrant
ELEVATION_BINS = 64
# Coordinates must stay below this (m) so that squared distances cannot overflow.
MAX_ABS_M = 1e150

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int32]
IndexArray = npt.NDArray[np.int64]


@numba.njit(cache=True, nogil=True, inline="always")
def stand_ins(x: float, y: float, z: float) -> tuple[float, float]:
    """(t, a): elevation stand-in in [-1, 1] and azimuth stand-in in [0, 4] of a direction.

    Both are strictly increasing in the true angles; (0, 0) at the origin.
    """
    ax, ay = abs(x), abs(y)
    den = math.sqrt(x * x + y * y) + abs(z)
    t = z / den if den > 0.0 else 0.0
    s = ax + ay
    p = ay / s if s > 0.0 else 0.0
    a = (p if x >= 0.0 else 2.0 - p) if y >= 0.0 else (4.0 - p if x >= 0.0 else 2.0 + p)
    return t, a


@numba.njit(cache=True, nogil=True, inline="always")
def bin_of(t: float, a: float, t_lo: float, per_t: float) -> int:
    """Row-major bin of the stand-ins (rows clamped to the grid's elevation span)."""
    e = min(max(int((t - t_lo) * per_t), 0), ELEVATION_BINS - 1)
    c = min(int(a * (AZIMUTH_BINS // 4)), AZIMUTH_BINS - 1)
    return e * AZIMUTH_BINS + c


@numba.njit(cache=True, nogil=True, fastmath={"reassoc"})
def _abs_sum(flat: FloatArray) -> float:
    """Sum of |coordinates|: NaN or inf if any is, and >= any single one (reassociated: the
    sum only feeds a threshold)."""
    acc = 0.0
    for i in range(flat.shape[0]):
        acc += abs(flat[i])
    return acc


@numba.njit(cache=True, nogil=True)
def _elevations(flat: FloatArray, out: FloatArray) -> tuple[float, float]:
    """Elevation stand-in of every point into out (2 at the origin, where rho + |z| is 0);
    returns its (min, max) over the points off the origin."""
    for i in range(out.shape[0]):
        x, y, z = flat[3 * i], flat[3 * i + 1], flat[3 * i + 2]
        den = math.sqrt(x * x + y * y) + abs(z)
        out[i] = z / den if den > 0.0 else 2.0
    lo, hi = 1.0, -1.0
    for i in range(out.shape[0]):
        lo = min(lo, out[i])
        hi = max(hi, out[i] if out[i] <= 1.0 else hi)
    return lo, hi


@numba.njit(cache=True, nogil=True)
def _keys(flat: FloatArray, t: FloatArray, t_lo: float, per_t: float, key: IntArray) -> int:
    """Grid bin of every point into key, -1 at the origin (there rho + |z| is 0; also where
    x^2 + y^2 underflows and z is 0: such points are scanned apart, exactly); returns the
    number of points at -1."""
    at_origin = 0
    for i in range(key.shape[0]):
        x, y = flat[3 * i], flat[3 * i + 1]
        ax, ay = abs(x), abs(y)
        s = ax + ay
        p = ay / s if s > 0.0 else 0.0
        a = (p if x >= 0.0 else 2.0 - p) if y >= 0.0 else (4.0 - p if x >= 0.0 else 2.0 + p)
        e = min(max(int((t[i] - t_lo) * per_t), 0), ELEVATION_BINS - 1)
        c = min(int(a * (AZIMUTH_BINS // 4)), AZIMUTH_BINS - 1)
        origin = t[i] > 1.0  # see `_elevations`
        key[i] = -1 if origin else e * AZIMUTH_BINS + c
        at_origin += origin
    return at_origin


@numba.njit(cache=True, nogil=True)
def _counting_sort(
    xyz: FloatArray, key: IntArray, n_bins: int
) -> tuple[IntArray, FloatArray, IntArray]:
    """CSR of the points by key (-1: left out), stable within a bin.

    Returns (n_bins + 1,) int32 offsets, (G, 3) float64 coordinates and (G,) int32 point
    indices, both in key order.
    """
    offsets = np.zeros(n_bins + 1, dtype=np.int32)
    for i in range(key.shape[0]):
        if key[i] >= 0:
            offsets[key[i] + 1] += 1
    for b in range(n_bins):
        offsets[b + 1] += offsets[b]
    fill = offsets[:-1].copy()
    order = np.empty(offsets[n_bins], dtype=np.int32)
    pts = np.empty((offsets[n_bins], 3))
    for i in range(key.shape[0]):
        b = key[i]
        if b >= 0:
            s = fill[b]
            fill[b] = s + 1
            order[s] = i
            pts[s, 0] = xyz[i, 0]
            pts[s, 1] = xyz[i, 1]
            pts[s, 2] = xyz[i, 2]
    return offsets, pts, order


@numba.njit(cache=True, nogil=True)
def _edges(t_lo: float, per_t: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Unit directions of the bin edges: (ELEVATION_BINS + 1,) (rho, z) cos and sin of the
    lower edge of each row, (AZIMUTH_BINS,) (x, y) of the lower edge of each column."""
    e_cos = np.empty(ELEVATION_BINS + 1)
    e_sin = np.empty(ELEVATION_BINS + 1)
    for e in range(ELEVATION_BINS + 1):
        t = min(max(t_lo + e / per_t, -1.0), 1.0)
        norm = math.sqrt((1.0 - abs(t)) ** 2 + t * t)
        e_cos[e] = (1.0 - abs(t)) / norm
        e_sin[e] = t / norm
    a_x = np.empty(AZIMUTH_BINS)
    a_y = np.empty(AZIMUTH_BINS)
    for c in range(AZIMUTH_BINS):
        quadrant, rest = divmod(4 * c, AZIMUTH_BINS)
        f = rest / AZIMUTH_BINS  # exact: a multiple of 1 / AZIMUTH_BINS
        if quadrant == 0:
            ex, ey = 1.0 - f, f
        elif quadrant == 1:
            ex, ey = -f, 1.0 - f
        elif quadrant == 2:
            ex, ey = f - 1.0, -f
        else:
            ex, ey = f, f - 1.0
        norm = math.sqrt(ex * ex + ey * ey)
        a_x[c] = ex / norm
        a_y[c] = ey / norm
    return e_cos, e_sin, a_x, a_y


@numba.njit(cache=True, nogil=True)
def build_grid(xyz: FloatArray) -> tuple[Any, ...]:
    """The direction grid of every point off the origin, and the points at the origin.

    Returns (usable, grid, origin): usable is False if a coordinate is NaN, infinite or
    beyond MAX_ABS_M (the rest is then empty); grid is (offsets, pts, order) of
    `_counting_sort`, t_lo and per_t (the rows' origin and rows per unit of t), then the
    edges of `_edges`; origin is (pts, order) of the points at the origin.
    """
    flat = xyz.reshape(-1)
    usable = _abs_sum(flat) < MAX_ABS_M
    n = xyz.shape[0] if usable else 0
    t = np.empty(n)
    t_lo, t_hi = _elevations(flat[: 3 * n], t)
    per_t = ELEVATION_BINS / max(t_hi - t_lo, 1e-9)
    key = np.empty(n, dtype=np.int32)
    at_origin = _keys(flat[: 3 * n], t, t_lo, per_t, key)
    offsets, pts, order = _counting_sort(xyz, key, ELEVATION_BINS * AZIMUTH_BINS)
    o_pts = np.empty((at_origin, 3))
    o_order = np.empty(at_origin, dtype=np.int32)
    s = 0
    for i in range(n):
        if key[i] < 0:
            o_pts[s, 0], o_pts[s, 1], o_pts[s, 2] = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            o_order[s] = i
            s += 1
    e_cos, e_sin, a_x, a_y = _edges(t_lo, per_t)
    grid = (offsets, pts, order, t_lo, per_t, e_cos, e_sin, a_x, a_y)
    return usable, grid, (o_pts, o_order)


@numba.njit(cache=True, nogil=True)
def points_within(xyz: FloatArray, r_max: float) -> tuple[FloatArray, IntArray]:
    """(P, 3) coordinates and (P,) indices of the points with squared range < r_max^2."""
    rr_max = r_max * r_max
    count = 0
    for i in range(xyz.shape[0]):
        count += xyz[i, 0] ** 2 + xyz[i, 1] ** 2 + xyz[i, 2] ** 2 < rr_max
    pts = np.empty((count, 3))
    order = np.empty(count, dtype=np.int32)
    s = 0
    for i in range(xyz.shape[0]):
        if xyz[i, 0] ** 2 + xyz[i, 1] ** 2 + xyz[i, 2] ** 2 < rr_max:
            pts[s, 0], pts[s, 1], pts[s, 2] = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            order[s] = i
            s += 1
    return pts, order
