"""Local PCA normals from the k nearest neighbours within a radius (numba, cached on disk).

The incidence of a point without a usable range-image normal comes from the plane through
its neighbourhood (rules in `lads.physics.modalities`). `lads.physics.sphere_knn` finds the
neighbours: the same exact k nearest as pykdtree's and scipy's k-d trees, from a grid of the
scan's directions (it hands scans it does not suit to pykdtree). The covariance and its
3 x 3 eigenproblem (cyclic Jacobi rotations) run in one compiled loop, because numpy's
batched matmul and eigh over ~10k tiny matrices took as long as the neighbour search.
Eigenvalues and vectors agree with LAPACK to ~1e-12 relative.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from lads.physics.sphere_knn import knn_within

_JACOBI_SWEEPS = 12


Pair = tuple[float, float]
# Eigenvalues, then the eigenvectors' components v[row][column] row by row (column i belongs
# to eigenvalue i): 3 + 9 floats.
Eigen = tuple[float, float, float, float, float, float, float, float, float, float, float, float]


@numba.njit(cache=True, nogil=True, inline="always")
def _rot(c: float, s: float, a: float, b: float) -> Pair:
    """One plane rotation of the pair (a, b) by cos c, sin s: (c a - s b, s a + c b)."""
    return c * a - s * b, s * a + c * b


@numba.njit(cache=True, nogil=True, inline="always")
def _cos_sin(mpp: float, mqq: float, mpq: float) -> Pair:
    """cos and sin of the Jacobi rotation that zeroes m[p, q] (non-zero) of a symmetric m."""
    theta = (mqq - mpp) / (2.0 * mpq)
    t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1))
    c = 1.0 / math.sqrt(t * t + 1.0)
    return c, t * c


@numba.njit(cache=True, nogil=True, inline="always")
def _jacobi_eigen(
    m00: float,
    m01: float,
    m02: float,
    m10: float,
    m11: float,
    m12: float,
    m20: float,
    m21: float,
    m22: float,
) -> Eigen:
    """Eigen-decomposition of the symmetric 3 x 3 m (row by row) by cyclic Jacobi rotations.

    Each rotation turns columns p, q of m (m <- m J), then its rows p, q (m <- J^T m), then
    the columns p, q of the eigenvectors, all nine entries kept; scalars, not arrays, so the
    matrix stays in registers.

    Returns:
        The eigenvalues m00, m11, m22 (unsorted), then the eigenvectors v00 .. v22 row by row
        (column i belongs to eigenvalue i).
    """
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    for _ in range(_JACOBI_SWEEPS):
        off = m01**2 + m02**2 + m12**2
        if off <= 1e-30 * (m00**2 + m11**2 + m22**2) or off == 0.0:
            break
        if m01 != 0.0:  # p, q = 0, 1
            c, s = _cos_sin(m00, m11, m01)
            m00, m01 = _rot(c, s, m00, m01)
            m10, m11 = _rot(c, s, m10, m11)
            m20, m21 = _rot(c, s, m20, m21)
            m00, m10 = _rot(c, s, m00, m10)
            m01, m11 = _rot(c, s, m01, m11)
            m02, m12 = _rot(c, s, m02, m12)
            v00, v01 = _rot(c, s, v00, v01)
            v10, v11 = _rot(c, s, v10, v11)
            v20, v21 = _rot(c, s, v20, v21)
        if m02 != 0.0:  # p, q = 0, 2
            c, s = _cos_sin(m00, m22, m02)
            m00, m02 = _rot(c, s, m00, m02)
            m10, m12 = _rot(c, s, m10, m12)
            m20, m22 = _rot(c, s, m20, m22)
            m00, m20 = _rot(c, s, m00, m20)
            m01, m21 = _rot(c, s, m01, m21)
            m02, m22 = _rot(c, s, m02, m22)
            v00, v02 = _rot(c, s, v00, v02)
            v10, v12 = _rot(c, s, v10, v12)
            v20, v22 = _rot(c, s, v20, v22)
        if m12 != 0.0:  # p, q = 1, 2
            c, s = _cos_sin(m11, m22, m12)
            m01, m02 = _rot(c, s, m01, m02)
            m11, m12 = _rot(c, s, m11, m12)
            m21, m22 = _rot(c, s, m21, m22)
            m10, m20 = _rot(c, s, m10, m20)
            m11, m21 = _rot(c, s, m11, m21)
            m12, m22 = _rot(c, s, m12, m22)
            v01, v02 = _rot(c, s, v01, v02)
            v11, v12 = _rot(c, s, v11, v12)
            v21, v22 = _rot(c, s, v21, v22)
    return m00, m11, m22, v00, v01, v02, v10, v11, v12, v20, v21, v22


@numba.njit(cache=True, nogil=True, inline="always")
def _patch_cos(
    xyz: npt.NDArray[np.float64],
    qi: int,
    nbrs: npt.NDArray[np.int64],
    count: int,
    min_planarity: float,
) -> tuple[float, bool]:
    """|cos| of the PCA normal of point qi's `count` neighbours (nbrs: (k,) in ascending
    distance, entries >= N missing), and whether the patch is planar enough."""
    n = xyz.shape[0]
    qx, qy, qz = xyz[qi, 0], xyz[qi, 1], xyz[qi, 2]
    s0 = s1 = s2 = 0.0  # the offsets' sums, then their mean
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0  # their products' sums, then the covariance
    for t in range(nbrs.shape[0]):
        i = nbrs[t]
        if i >= n:
            continue
        off0 = xyz[i, 0] - qx
        off1 = xyz[i, 1] - qy
        off2 = xyz[i, 2] - qz
        s0 += off0
        s1 += off1
        s2 += off2
        c00 += off0 * off0
        c01 += off0 * off1
        c02 += off0 * off2
        c11 += off1 * off1
        c12 += off1 * off2
        c22 += off2 * off2
    s0, s1, s2 = s0 / count, s1 / count, s2 / count
    c00, c01, c02 = c00 / count - s0 * s0, c01 / count - s0 * s1, c02 / count - s0 * s2
    c11, c12, c22 = c11 / count - s1 * s1, c12 / count - s1 * s2, c22 / count - s2 * s2
    d0, d1, d2, v00, v01, v02, v10, v11, v12, v20, v21, v22 = _jacobi_eigen(
        c00, c01, c02, c01, c11, c12, c02, c12, c22
    )
    lo, hi, d_lo, d_hi = 0, 0, d0, d0  # the first smallest, the last largest eigenvalue
    if d1 < d_lo:
        lo, d_lo = 1, d1
    if d1 >= d_hi:
        hi, d_hi = 1, d1
    if d2 < d_lo:
        lo, d_lo = 2, d2
    if d2 >= d_hi:
        hi, d_hi = 2, d2
    mid = 3 - lo - hi if lo != hi else (lo + 1) % 3
    d_mid = d0 if mid == 0 else (d1 if mid == 1 else d2)
    if d_mid < min_planarity * max(d_hi, 1e-300):
        return 0.0, False
    nx, ny, nz = (v00, v10, v20) if lo == 0 else ((v01, v11, v21) if lo == 1 else (v02, v12, v22))
    norm = math.sqrt(nx * nx + ny * ny + nz * nz) * math.sqrt(qx * qx + qy * qy + qz * qz)
    return (min(abs(nx * qx + ny * qy + nz * qz) / norm, 1.0) if norm > 0.0 else 0.0), True


@numba.njit(cache=True, nogil=True)
def _plane_cos(
    xyz: npt.NDArray[np.float64],
    query: npt.NDArray[np.int64],
    neighbours: npt.NDArray[np.int64],
    min_neighbours: int,
    min_planarity: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """(M,) |cos| of the PCA normal of each query's neighbours and (M,) found flags.

    `neighbours` is (M, k) in ascending distance (the sums run in that order); entries >= N
    mark missing neighbours (the k-d trees' convention).
    """
    n = xyz.shape[0]
    m = query.shape[0]
    cos = np.zeros(m)
    found = np.zeros(m, dtype=np.bool_)
    for j in range(m):
        count = 0
        for t in range(neighbours.shape[1]):
            if neighbours[j, t] < n:
                count += 1
        if count >= min_neighbours:
            cos[j], found[j] = _patch_cos(xyz, query[j], neighbours[j], count, min_planarity)
    return cos, found


def neighbour_cos(
    xyz64: npt.NDArray[np.float64],
    query: npt.NDArray[np.intp],
    *,
    k: int,
    radius_m: float,
    min_neighbours: int,
    min_planarity: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """PCA-normal |cos(incidence)| of the `query` points.

    Args:
        xyz64: (N, 3) float64 coordinates in m, sensor at the origin.
        query: (M,) indices into xyz64.
        k: at most this many neighbours, the query point itself included.
        radius_m: neighbours lie closer than this (strictly, as the trees' distance_upper_bound).
        min_neighbours: fewer neighbours than this: not found.
        min_planarity: second / largest covariance eigenvalue below this (points on a
            line, as along one ring): not found.

    Returns:
        (M,) float64 |cos| between the normal and the ray in [0, 1]; (M,) bool found.

    Raises:
        ConfigError, InvalidPointsError: see `lads.physics.sphere_knn.knn_within`.
    """
    xyz = np.ascontiguousarray(xyz64, dtype=np.float64)
    q = np.ascontiguousarray(query, dtype=np.int64)
    if len(q) == 0 or len(xyz) == 0:
        return np.zeros(len(q)), np.zeros(len(q), dtype=bool)
    idx, _ = knn_within(xyz, q, k=k, radius_m=radius_m)
    return _plane_cos(xyz, q, idx, int(min_neighbours), float(min_planarity))
