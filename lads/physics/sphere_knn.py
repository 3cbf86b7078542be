"""Exact k nearest neighbours within a radius, for a scan seen from the origin (numba).

The points sit in the direction grid of `lads.physics.sphere_grid` (elevation rows by
azimuth columns). A query scans the bins in a window around its own and widens it in rounds,
each side until its certified bound reaches a target distance, until no point outside can be
nearer than its current k-th neighbour (or the radius):

- a point whose ray makes an angle >= psi with the query's ray lies at least
  r_q sin(min(psi, 90 deg)) from it (r_q: the query's range), and an elevation difference
  >= d gives psi >= d;
- a point whose azimuth differs by >= d lies at least rho_q sin(min(d, 90 deg)) from it
  horizontally (rho_q: the query's horizontal range).

Each bound is the query's distance to the ray of a window edge (a cross product with the
edge's exact direction), less a relative slack for rounding, in the (rho, z) half-plane for
elevation and the (x, y) plane for azimuth; a window reaching the grid's end, or every
azimuth, is unbounded on that side. Points at the origin have no direction and are offered
to every query besides. Each query starts from the last one's k-th distance, and is capped
by the last one's neighbours (consecutive queries of a scan are often neighbours).

Queries within NEAR_RADII radii of the sensor whose window would need more than 30 deg
(there directions say little) are compared with every point within NEAR_RADII + 1 radii, or,
if that is more than NEAR_PAIRS pairs, searched by pykdtree on those points. If the grid scans
more than WORK_PER_QUERY points a query (dense clusters at the sensor, falling snow), the rest
of the scan goes to pykdtree on all points, as before. Both are exact as well.

Squared distances are summed as pykdtree sums them (dx^2 + dy^2 + dz^2 in float64), a
neighbour lies strictly inside the radius (pykdtree and scipy both leave out a point at
exactly the radius), and neighbours come in ascending distance: the same sets as the trees'.
Points at exactly equal distances may come in another order, or at the k-th place be another
of the equals.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt
from pykdtree.kdtree import KDTree

from lads.errors import ConfigError, InvalidPointsError
from lads.physics.sphere_grid import (
    AZIMUTH_BINS,
    ELEVATION_BINS,
    MAX_ABS_M,
    FloatArray,
    IndexArray,
    IntArray,
    bin_of,
    build_grid,
    points_within,
    stand_ins,
)

# A query whose window would need an angle beyond asin(this) (30 deg) is too close to the
# sensor for directions to help; it can only be one within 1 / this = NEAR_RADII radii.
_NEAR_SIN = 0.5
NEAR_RADII = 1.0 / _NEAR_SIN
# Relative slack on every certified bound: the stand-ins, edges and cross products round at
# ~1e-15 relative (both stand-ins have slopes within [1/2, 1] of the true angles).
_SLACK = 1e-9
# Relative margin on the rounded ranges that pick the points near queries are compared with.
_MARGIN = 1e-6
# Points a query may scan on average before the rest of the scan goes to a k-d tree: ~3x
# what a 64-beam scan needs (~110), and about what a tree query costs; dense clusters at the
# sensor and falling snow need more.
WORK_PER_QUERY = 300
WORK_ALLOWANCE = 20_000  # points scanned before the average counts (a few costly queries)
# Queries near the sensor times points within NEAR_RADII + 1 radii up to which those queries
# are compared with all of them (~1 ms); beyond, a k-d tree of those points.
NEAR_PAIRS = 1_000_000
# Points per leaf of the fallback k-d tree (pykdtree's default is 16; 32 was faster here).
TREE_LEAF_POINTS = 32


@numba.njit(cache=True, nogil=True, inline="always")
def _insert(d2: float, i: int, count: int, k: int, best_d2: FloatArray, best_i: IndexArray) -> int:
    """Insert neighbour i at squared distance d2 into the ascending list; returns the count."""
    pos = count if count < k else k - 1
    while pos > 0 and best_d2[pos - 1] > d2:  # equal distances keep their arrival order
        best_d2[pos] = best_d2[pos - 1]
        best_i[pos] = best_i[pos - 1]
        pos -= 1
    best_d2[pos] = d2
    best_i[pos] = i
    return count + 1 if count < k else k


@numba.njit(cache=True, nogil=True, inline="always")
def _scan(
    start: int, stop: int, pts: FloatArray, order: IntArray, qx: float, qy: float, qz: float,
    cap: float, k: int, count: int, best_d2: FloatArray, best_i: IndexArray,
) -> int:  # fmt: skip
    """Offer the sorted points start..stop-1 (those with d2 < cap) to the neighbour list."""
    limit = best_d2[k - 1] if count == k else cap
    for s in range(start, stop):
        dx = qx - pts[s, 0]
        dy = qy - pts[s, 1]
        dz = qz - pts[s, 2]
        d2 = dx * dx + dy * dy + dz * dz  # pykdtree's sum, in its order
        if d2 < limit:
            count = _insert(d2, order[s], count, k, best_d2, best_i)
            limit = best_d2[k - 1] if count == k else cap
    return count


@numba.njit(cache=True, nogil=True, inline="always")
def _edge_bound(px: float, py: float, ex: float, ey: float, norm: float, slack: float) -> float:
    """Certified squared distance from the planar point (px, py), of length norm, to every
    point beyond the edge ray along the unit (ex, ey): its distance to the ray less slack."""
    if px * ex + py * ey < 0.0:
        d = norm - slack  # the ray's nearest point is the origin
    else:
        d = abs(px * ey - py * ex) - slack
    return d * d if d > 0.0 else 0.0


@numba.njit(cache=True, nogil=True, inline="always")
def _scan_rows(
    e0: int, e1: int, c: int, n_cols: int, offsets: IntArray, pts: FloatArray,
    order: IntArray, qx: float, qy: float, qz: float, cap: float, k: int, count: int,
    best_d2: FloatArray, best_i: IndexArray, work: IndexArray,
) -> int:  # fmt: skip
    """Scan n_cols columns from c on (wrapping) of the rows e0..e1; work[0] counts points."""
    if n_cols <= 0:
        return count
    first = min(n_cols, AZIMUTH_BINS - c)  # the columns before the wrap
    for e in range(e0, e1 + 1):
        b = e * AZIMUTH_BINS
        work[0] += offsets[b + c + first] - offsets[b + c]
        if first < n_cols:
            work[0] += offsets[b + n_cols - first] - offsets[b]
        count = _scan(offsets[b + c], offsets[b + c + first], pts, order, qx, qy, qz, cap, k,
                      count, best_d2, best_i)  # fmt: skip
        if first < n_cols:
            count = _scan(offsets[b], offsets[b + n_cols - first], pts, order, qx, qy, qz, cap,
                          k, count, best_d2, best_i)  # fmt: skip
    return count


@numba.njit(cache=True, nogil=True, inline="always")
def _grid_search(
    qx: float, qy: float, qz: float, grid: tuple, cap: float, guess2: float, esc2: float,  # type: ignore[type-arg]
    k: int, count: int, best_d2: FloatArray, best_i: IndexArray, work: IndexArray,
) -> int:  # fmt: skip
    """Neighbours of a point off the origin through the grid, after `count` already listed.

    The window is rows e0..e1 by the `width` columns c0.. (wrapping); each round widens every
    side until its bound reaches `target`, which starts at guess2 and at least quadruples.
    Returns the count, or -1 if the target reaches esc2 (directions cannot serve the query).
    work[0] counts the points scanned.
    """
    offsets, pts, order, t_lo, per_t, e_cos, e_sin, a_x, a_y = grid
    t, a = stand_ins(qx, qy, qz)
    b = bin_of(t, a, t_lo, per_t)
    e0 = e1 = b // AZIMUTH_BINS
    c0 = c1 = b - e0 * AZIMUTH_BINS
    width = 1
    rho = math.sqrt(qx * qx + qy * qy)
    rq = math.sqrt(qx * qx + qy * qy + qz * qz)
    slack = _SLACK * rq
    inf = np.inf
    count = _scan(offsets[b], offsets[b + 1], pts, order, qx, qy, qz, cap, k, count, best_d2,
                  best_i)  # fmt: skip
    work[0] += offsets[b + 1] - offsets[b]
    certified = 0.0  # squared distance to every point outside the window, at least
    while True:
        limit = best_d2[k - 1] if count == k else cap
        if certified >= limit:
            return count
        target = min(limit, max(4.0 * certified, guess2))
        if target >= esc2:
            return -1
        n0, n1, m0, m1, w = e0, e1, c0, c1, width
        while True:
            lo = inf if n0 == 0 else _edge_bound(rho, qz, e_cos[n0], e_sin[n0], rq, slack)
            if lo >= target:
                break
            n0 -= 1
        while True:
            hi = inf if n1 == ELEVATION_BINS - 1 else _edge_bound(
                rho, qz, e_cos[n1 + 1], e_sin[n1 + 1], rq, slack)  # fmt: skip
            if hi >= target:
                break
            n1 += 1
        left = right = inf
        while w < AZIMUTH_BINS:
            left = _edge_bound(qx, qy, a_x[m0], a_y[m0], rho, slack)
            if left >= target:
                break
            m0 = m0 - 1 if m0 > 0 else AZIMUTH_BINS - 1
            w += 1
        while w < AZIMUTH_BINS:
            up = m1 + 1 if m1 + 1 < AZIMUTH_BINS else 0
            right = _edge_bound(qx, qy, a_x[up], a_y[up], rho, slack)
            if right >= target:
                break
            m1 = up
            w += 1
        if w == AZIMUTH_BINS:
            left = right = inf
        # the old rows gain columns on both sides, the new rows get all of them
        n_left = c0 - m0 if c0 >= m0 else c0 - m0 + AZIMUTH_BINS
        right_start = c1 + 1 if c1 + 1 < AZIMUTH_BINS else 0
        count = _scan_rows(e0, e1, m0, n_left, offsets, pts, order, qx, qy, qz, cap, k, count,
                           best_d2, best_i, work)  # fmt: skip
        count = _scan_rows(e0, e1, right_start, w - width - n_left, offsets, pts, order, qx, qy,
                           qz, cap, k, count, best_d2, best_i, work)  # fmt: skip
        count = _scan_rows(n0, e0 - 1, m0, w, offsets, pts, order, qx, qy, qz, cap, k, count,
                           best_d2, best_i, work)  # fmt: skip
        count = _scan_rows(e1 + 1, n1, m0, w, offsets, pts, order, qx, qy, qz, cap, k, count,
                           best_d2, best_i, work)  # fmt: skip
        e0, e1, c0, c1, width = n0, n1, m0, m1, w
        certified = min(min(lo, hi), min(left, right))


@numba.njit(cache=True, nogil=True, inline="always")
def _cap(
    qx: float, qy: float, qz: float, xyz: FloatArray, prev: IndexArray, prev_count: int,
    k: int, r2: float,
) -> float:  # fmt: skip
    """The squared distance a neighbour must stay below: r2, or just above the farthest of
    the previous query's k neighbours when all lie within r2 (k points then do)."""
    if prev_count < k:
        return r2
    far = 0.0
    for t in range(k):
        i = prev[t]
        dx = qx - xyz[i, 0]
        dy = qy - xyz[i, 1]
        dz = qz - xyz[i, 2]
        far = max(far, dx * dx + dy * dy + dz * dz)
    return np.nextafter(far, np.inf) if far < r2 else r2


@numba.njit(cache=True, nogil=True)
def _knn_grid(
    xyz: FloatArray, query: IndexArray, k: int, radius: float, work_per_query: int,
    work_allowance: int, near_pairs: int,
) -> tuple:  # type: ignore[type-arg]  # fmt: skip
    """The neighbours of the queries the direction grid serves, in the given order.

    Consecutive queries of a scan are often neighbours, so each starts from the last one's
    k-th distance and is capped by its neighbours (`_cap`).

    Returns (usable, idx, d2, pending, stop): usable is False for NaN, infinite or absurd
    coordinates; (M, k) int64 indices (N where missing) and (M, k) squared distances (inf);
    pending: positions of the queries too near the sensor for directions and too many to
    compare with every point within NEAR_RADII + 1 radii (near_pairs); stop: the queries
    from this position on were left unsearched, the grid having scanned more than
    work_per_query points a query, after work_allowance (M if it never did).
    """
    m = query.shape[0]
    idx = np.full((m, k), xyz.shape[0], dtype=np.int64)
    d2 = np.full((m, k), np.inf)
    pending = np.empty(m, dtype=np.int64)
    usable, grid, origin = build_grid(xyz)
    if not usable:
        return False, idx, d2, pending[:0], 0
    o_pts, o_order = origin
    r2 = radius * radius
    near2 = (NEAR_RADII * radius) ** 2
    guess2 = 1e-4 * r2  # the first round's target; then the last query's k-th distance
    best_d2 = np.empty(k)
    best_i = np.empty(k, dtype=np.int64)
    work = np.zeros(1, dtype=np.int64)
    n_pending = 0
    count = 0
    for j in range(m):
        if work[0] > work_per_query * j + work_allowance:
            return True, idx, d2, pending[:n_pending], j
        qi = query[j]
        qx, qy, qz = xyz[qi, 0], xyz[qi, 1], xyz[qi, 2]
        cap = _cap(qx, qy, qz, xyz, best_i, count, k, r2)
        rq2 = qx * qx + qy * qy + qz * qz
        esc2 = _NEAR_SIN * _NEAR_SIN * rq2 if rq2 < near2 else np.inf
        count = _scan(0, o_order.shape[0], o_pts, o_order, qx, qy, qz, cap, k, 0, best_d2,
                      best_i)  # fmt: skip
        if rq2 > 0.0:
            count = _grid_search(qx, qy, qz, grid, cap, guess2, esc2, k, count, best_d2,
                                 best_i, work)  # fmt: skip
        else:
            count = -1
        if count < 0:
            pending[n_pending] = j
            n_pending += 1
            count = 0
            continue
        if count == k:
            guess2 = max(best_d2[k - 1], 1e-12 * r2)  # > 0, so that every round widens
        for t in range(count):
            idx[j, t] = best_i[t]
            d2[j, t] = best_d2[t]
    if n_pending == 0:
        return True, idx, d2, pending[:0], m
    # Their neighbours lie within NEAR_RADII + 1 radii of the sensor: if few, compare them all.
    near_pts, near_order = points_within(xyz, (NEAR_RADII + 1.0) * radius * (1.0 + _MARGIN))
    if n_pending * near_order.shape[0] > near_pairs:
        return True, idx, d2, pending[:n_pending], m
    for u in range(n_pending):
        j = pending[u]
        qi = query[j]
        count = _scan(0, near_order.shape[0], near_pts, near_order, xyz[qi, 0], xyz[qi, 1],
                      xyz[qi, 2], r2, k, 0, best_d2, best_i)  # fmt: skip
        for t in range(count):
            idx[j, t] = best_i[t]
            d2[j, t] = best_d2[t]
    return True, idx, d2, pending[:0], m


def checked_arguments(
    xyz64: npt.ArrayLike, query: npt.ArrayLike, k: int, radius_m: float
) -> tuple[FloatArray, IndexArray]:
    """(N, 3) float64 points and (M,) int64 queries, C-contiguous; raises on bad arguments.

    Raises:
        ConfigError: k < 1, or a radius that is not finite and positive.
        InvalidPointsError: xyz not (N, 3), or query indices outside 0..N-1.
    """
    if int(k) < 1 or not 0.0 < float(radius_m) < np.inf:
        raise ConfigError(f"k={k}, radius_m={radius_m}: need k >= 1 and 0 < radius_m < inf.")
    xyz = np.ascontiguousarray(xyz64, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InvalidPointsError(f"xyz: shape {xyz.shape}, expected (N, 3) coordinates.")
    q = np.ascontiguousarray(query, dtype=np.int64).reshape(-1)
    if len(q) and (q.min() < 0 or q.max() >= len(xyz)):
        raise InvalidPointsError(f"query: indices must lie in 0..{len(xyz) - 1}.")
    return xyz, q


def _tree_fill(
    xyz: FloatArray, q: IndexArray, rows: IndexArray, k: int, radius: float,
    idx: IndexArray, d2: FloatArray, points: IndexArray | None,
) -> None:  # fmt: skip
    """Neighbours of the queries q[rows] into idx[rows], d2[rows] by pykdtree, built on
    `points` (indices into xyz, holding every candidate of these queries) or on all of xyz."""
    data = xyz if points is None else xyz[points]
    k_eff = min(k, len(data))
    tree = KDTree(data, leafsize=TREE_LEAF_POINTS)
    dist2, nb = tree.query(xyz[q[rows]], k=k_eff, distance_upper_bound=radius, sqr_dists=True)
    nb = np.asarray(nb, dtype=np.int64).reshape(len(rows), k_eff)
    if points is not None:  # back to indices into xyz; the tree's "missing" is len(data)
        nb = np.append(points, len(xyz))[np.minimum(nb, len(data))]
    idx[rows, :k_eff] = np.minimum(nb, len(xyz))
    d2[rows, :k_eff] = np.asarray(dist2).reshape(len(rows), k_eff)


def knn_within(
    xyz64: npt.ArrayLike, query: npt.ArrayLike, *, k: int, radius_m: float
) -> tuple[IndexArray, FloatArray]:
    """The k nearest points strictly within radius_m of each query point, itself included.

    Args:
        xyz64: (N, 3) coordinates in m (cast to float64), sensor at the origin.
        query: (M,) indices into xyz64.
        k: at most this many neighbours (>= 1).
        radius_m: neighbours lie at a distance < radius_m (finite, > 0).

    Returns:
        (M, k) int64 neighbour indices in ascending distance, N where fewer than k lie within
        the radius; (M, k) float64 squared distances in m^2, inf where missing.

    Raises:
        ConfigError: see `checked_arguments`.
        InvalidPointsError: see `checked_arguments`; also NaN, infinite or absurd (>= 1e150
            m) coordinates.
    """
    xyz, q = checked_arguments(xyz64, query, k, radius_m)
    k, radius = int(k), float(radius_m)
    if len(q) == 0:
        return np.zeros((0, k), dtype=np.int64), np.zeros((0, k))
    usable, idx, d2, pending, stop = _knn_grid(
        xyz, q, k, radius, WORK_PER_QUERY, WORK_ALLOWANCE, NEAR_PAIRS
    )
    if not usable:
        raise InvalidPointsError(
            f"xyz holds NaN, infinite or absurd coordinates (|value| >= {MAX_ABS_M:g} m); "
            "pass finite points in metres."
        )
    if stop < len(q):  # the grid does not pay off on this scan: a tree for the rest
        rows = np.concatenate([pending, np.arange(stop, len(q))])
        _tree_fill(xyz, q, rows, k, radius, idx, d2, None)
    elif len(pending):  # their neighbours lie within NEAR_RADII + 1 radii of the sensor
        r_max = (NEAR_RADII + 1.0) * radius * (1.0 + _MARGIN)
        near = np.flatnonzero(np.einsum("ij,ij->i", xyz, xyz) < r_max * r_max)
        _tree_fill(xyz, q, pending, k, radius, idx, d2, near)
    return idx, d2
