"""The window search of `lads.physics.sphere_knn` (numba, inlined into its compiled pass): a
query's bins scanned in widening rounds until the certified bounds of the module doc there
reach its k-th distance, and the sorted insertion of each candidate."""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from lads.physics.sphere_grid import (
    AZIMUTH_BINS,
    ELEVATION_BINS,
    FloatArray,
    IndexArray,
    IntArray,
    bin_of,
    stand_ins,
)

# Relative slack on every certified bound: the stand-ins, edges and cross products round at
# ~1e-15 relative (both stand-ins have slopes within [1/2, 1] of the true angles).
_SLACK = 1e-9


@numba.njit(cache=True, nogil=True, inline="always")
def insert(d2: float, i: int, count: int, k: int, best_d2: FloatArray, best_i: IndexArray) -> int:
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
def scan_points(
    start: int,
    stop: int,
    pts: FloatArray,
    order: IntArray,
    qx: float,
    qy: float,
    qz: float,
    cap: float,
    k: int,
    count: int,
    best_d2: FloatArray,
    best_i: IndexArray,
) -> int:
    """Offer the sorted points start..stop-1 (those with d2 < cap) to the neighbour list."""
    limit = best_d2[k - 1] if count == k else cap
    for s in range(start, stop):
        dx = qx - pts[s, 0]
        dy = qy - pts[s, 1]
        dz = qz - pts[s, 2]
        d2 = dx * dx + dy * dy + dz * dz  # pykdtree's sum, in its order
        if d2 < limit:
            count = insert(d2, order[s], count, k, best_d2, best_i)
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
    e0: int,
    e1: int,
    c: int,
    n_cols: int,
    offsets: IntArray,
    pts: FloatArray,
    order: IntArray,
    qx: float,
    qy: float,
    qz: float,
    cap: float,
    k: int,
    count: int,
    best_d2: FloatArray,
    best_i: IndexArray,
    work: IndexArray,
) -> int:
    """Scan n_cols columns from c on (wrapping) of the rows e0..e1; work[0] counts points."""
    if n_cols <= 0:
        return count
    first = min(n_cols, AZIMUTH_BINS - c)  # the columns before the wrap
    for e in range(e0, e1 + 1):
        b = e * AZIMUTH_BINS
        work[0] += offsets[b + c + first] - offsets[b + c]
        if first < n_cols:
            work[0] += offsets[b + n_cols - first] - offsets[b]
        count = scan_points(
            offsets[b + c],
            offsets[b + c + first],
            pts,
            order,
            qx,
            qy,
            qz,
            cap,
            k,
            count,
            best_d2,
            best_i,
        )
        if first < n_cols:
            count = scan_points(
                offsets[b],
                offsets[b + n_cols - first],
                pts,
                order,
                qx,
                qy,
                qz,
                cap,
                k,
                count,
                best_d2,
                best_i,
            )
    return count


@numba.njit(cache=True, nogil=True, inline="always")
def grid_search(
    qx: float,
    qy: float,
    qz: float,
    grid: tuple[Any, ...],
    cap: float,
    guess2: float,
    esc2: float,
    k: int,
    count: int,
    best_d2: FloatArray,
    best_i: IndexArray,
    work: IndexArray,
) -> int:
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
    count = scan_points(
        offsets[b], offsets[b + 1], pts, order, qx, qy, qz, cap, k, count, best_d2, best_i
    )
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
            hi = (
                inf
                if n1 == ELEVATION_BINS - 1
                else _edge_bound(rho, qz, e_cos[n1 + 1], e_sin[n1 + 1], rq, slack)
            )
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
        count = _scan_rows(
            e0,
            e1,
            m0,
            n_left,
            offsets,
            pts,
            order,
            qx,
            qy,
            qz,
            cap,
            k,
            count,
            best_d2,
            best_i,
            work,
        )
        count = _scan_rows(
            e0,
            e1,
            right_start,
            w - width - n_left,
            offsets,
            pts,
            order,
            qx,
            qy,
            qz,
            cap,
            k,
            count,
            best_d2,
            best_i,
            work,
        )
        count = _scan_rows(
            n0, e0 - 1, m0, w, offsets, pts, order, qx, qy, qz, cap, k, count, best_d2, best_i, work
        )
        count = _scan_rows(
            e1 + 1, n1, m0, w, offsets, pts, order, qx, qy, qz, cap, k, count, best_d2, best_i, work
        )
        e0, e1, c0, c1, width = n0, n1, m0, m1, w
        certified = min(min(lo, hi), min(left, right))
