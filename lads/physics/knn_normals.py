"""Local PCA normals from the k nearest neighbours within a radius (numba, cached on disk).

The incidence of a point without a usable range-image normal comes from the plane through
its neighbourhood (rules in `lads.physics.modalities`). `lads.physics.sphere_knn` finds the
neighbours: the same exact k nearest as pykdtree's and scipy's k-d trees, from a grid of the
scan's directions (it hands scans it does not suit to pykdtree). The covariance and its
3 x 3 eigenproblem run in one compiled loop, because numpy's batched matmul and eigh over
~10k tiny matrices took as long as the neighbour search.

The eigenproblem is solved in closed form (docs/physics.md §10.3): the eigenvalues from the
trigonometric solution of the characteristic cubic, the normal as the longest cross product
of two rows of C - lambda_min I (each row is orthogonal to the normal). On the planar patches
the rule keeps, the smallest eigenvalue lies far below the other two, where this is as
accurate as LAPACK: |cos| agrees with numpy's eigh to ~1e-12 (tests), and it costs a third
of the cyclic Jacobi rotations it replaced.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from lads.physics.sphere_knn import knn_within

Triple = tuple[float, float, float]


@numba.njit(cache=True, nogil=True, inline="always")
def _eigenvalues(
    c00: float, c01: float, c02: float, c11: float, c12: float, c22: float
) -> tuple[float, float, float, bool]:
    """(low, middle, high) eigenvalues of the symmetric 3 x 3 matrix C (upper triangle),
    and False when C is a multiple of the identity (every direction an eigenvector) or too
    small to solve (|C - qI| below ~1e-100).

    Trigonometric solution of det(C - lambda I) = 0 with C = q I + p B, det(B) = 2 r:
    lambda = q + 2 p cos(acos(r) / 3 + 2 pi j / 3), j = 0 (high), 1 (low); the middle one
    from the trace.
    """
    q = (c00 + c11 + c22) / 3.0
    a0, a1, a2 = c00 - q, c11 - q, c22 - q
    p2 = a0 * a0 + a1 * a1 + a2 * a2 + 2.0 * (c01 * c01 + c02 * c02 + c12 * c12)
    if not p2 > 0.0:
        return q, q, q, False
    p = math.sqrt(p2 / 6.0)
    det = a0 * (a1 * a2 - c12 * c12) - c01 * (c01 * a2 - c12 * c02) + c02 * (c01 * c12 - a1 * c02)
    r = det / (2.0 * p * p * p)
    if not math.isfinite(r):  # p^3 underflows: offsets far below any sensor's resolution
        return q, q, q, False
    r = min(max(r, -1.0), 1.0)
    phi = math.acos(r) / 3.0
    high = q + 2.0 * p * math.cos(phi)
    low = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return low, 3.0 * q - high - low, high, True


@numba.njit(cache=True, nogil=True, inline="always")
def _null_direction(
    c00: float, c01: float, c02: float, c11: float, c12: float, c22: float, lam: float
) -> Triple:
    """An (unnormalised) eigenvector of C for the eigenvalue lam: the longest of the cross
    products of two rows of C - lam I, all three orthogonal to it."""
    r00, r11, r22 = c00 - lam, c11 - lam, c22 - lam
    ax, ay, az = c01 * c12 - c02 * r11, c02 * c01 - r00 * c12, r00 * r11 - c01 * c01
    bx, by, bz = c01 * r22 - c02 * c12, c02 * c02 - r00 * r22, r00 * c12 - c01 * c02
    cx, cy, cz = r11 * r22 - c12 * c12, c12 * c02 - c01 * r22, c01 * c12 - r11 * c02
    na = ax * ax + ay * ay + az * az
    nb = bx * bx + by * by + bz * bz
    nc = cx * cx + cy * cy + cz * cz
    if na >= nb and na >= nc:
        return ax, ay, az
    return (bx, by, bz) if nb >= nc else (cx, cy, cz)


@numba.njit(cache=True, nogil=True, inline="always")
def _patch_cos(
    xyz: npt.NDArray[np.float64],
    qi: int,
    nbrs: npt.NDArray[np.int64],
    count: int,
    min_planarity: float,
) -> tuple[float, bool]:
    """|cos| of the PCA normal of point qi's `count` neighbours (nbrs: (k,) in ascending
    distance, entries >= N missing), and whether the patch is planar enough (a covariance
    with no preferred direction is not)."""
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
    low, middle, high, directed = _eigenvalues(c00, c01, c02, c11, c12, c22)
    if not directed or middle < min_planarity * max(high, 1e-300):
        return 0.0, False
    nx, ny, nz = _null_direction(c00, c01, c02, c11, c12, c22, low)
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
