"""Exact k nearest neighbours within a radius, for a scan seen from the origin (numba).

The points sit in the direction grid of `lads.physics.sphere_grid` (elevation rows by
azimuth columns). A query scans the bins in a window around its own and widens it in rounds,
each side until its certified bound reaches a target distance, until no point outside can be
nearer than its current k-th neighbour (or the radius; the search itself is
`lads.physics.sphere_window`):

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

from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from pykdtree.kdtree import KDTree

from lads.errors import ConfigError, InvalidPointsError
from lads.physics.sphere_grid import (
    MAX_ABS_M,
    FloatArray,
    IndexArray,
    build_grid,
    points_within,
)
from lads.physics.sphere_window import grid_search, scan_points

# A query whose window would need an angle beyond asin(this) (30 deg) is too close to the
# sensor for directions to help; it can only be one within 1 / this = NEAR_RADII radii.
_NEAR_SIN = 0.5
NEAR_RADII = 1.0 / _NEAR_SIN
# Relative margin on the rounded ranges that pick the points near queries are compared with.
_MARGIN = 1e-6
# Points a query may scan on average before the rest of the scan goes to a k-d tree: a few
# times what a 64-beam scan needs, and about what a tree query costs; dense clusters at the
# sensor and falling snow need more.
WORK_PER_QUERY = 300
WORK_ALLOWANCE = 20_000  # points scanned before the average counts (a few costly queries)
# Queries near the sensor times points within NEAR_RADII + 1 radii up to which those queries
# are compared with all of them (cheaper than a tree then); beyond, a k-d tree of those points.
NEAR_PAIRS = 1_000_000
# Points per leaf of the fallback k-d tree (pykdtree's default is 16; larger leaves made the
# build plus queries of a scan faster, with the same neighbours).
TREE_LEAF_POINTS = 32


@numba.njit(cache=True, nogil=True, inline="always")
def _cap(
    qx: float,
    qy: float,
    qz: float,
    xyz: FloatArray,
    prev: IndexArray,
    prev_count: int,
    k: int,
    r2: float,
) -> float:
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
    xyz: FloatArray,
    query: IndexArray,
    k: int,
    radius: float,
    work_per_query: int,
    work_allowance: int,
    near_pairs: int,
) -> tuple[Any, ...]:
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
        count = scan_points(
            0, o_order.shape[0], o_pts, o_order, qx, qy, qz, cap, k, 0, best_d2, best_i
        )
        if rq2 > 0.0:
            count = grid_search(
                qx, qy, qz, grid, cap, guess2, esc2, k, count, best_d2, best_i, work
            )
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
        count = scan_points(
            0,
            near_order.shape[0],
            near_pts,
            near_order,
            xyz[qi, 0],
            xyz[qi, 1],
            xyz[qi, 2],
            r2,
            k,
            0,
            best_d2,
            best_i,
        )
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
    xyz: FloatArray,
    q: IndexArray,
    rows: IndexArray,
    k: int,
    radius: float,
    idx: IndexArray,
    d2: FloatArray,
    points: IndexArray | None,
) -> None:
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
