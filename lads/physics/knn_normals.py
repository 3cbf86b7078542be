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


@numba.njit(cache=True, nogil=True)
def _jacobi_eigen(m: npt.NDArray[np.float64], v: npt.NDArray[np.float64]) -> None:
    """Diagonalise the symmetric 3 x 3 `m` in place; `v` receives the eigenvectors (columns).

    Afterwards m's diagonal holds the eigenvalues (unsorted), column i of v belongs to m[i, i].
    """
    for a in range(3):
        for b in range(3):
            v[a, b] = 1.0 if a == b else 0.0
    for _ in range(_JACOBI_SWEEPS):
        off = m[0, 1] ** 2 + m[0, 2] ** 2 + m[1, 2] ** 2
        if off <= 1e-30 * (m[0, 0] ** 2 + m[1, 1] ** 2 + m[2, 2] ** 2) or off == 0.0:
            return
        for p in range(2):
            for q in range(p + 1, 3):
                if m[p, q] == 0.0:
                    continue
                theta = (m[q, q] - m[p, p]) / (2.0 * m[p, q])
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(3):  # columns p, q of m <- m J
                    mkp, mkq = m[k, p], m[k, q]
                    m[k, p] = c * mkp - s * mkq
                    m[k, q] = s * mkp + c * mkq
                for k in range(3):  # rows p, q of m <- J^T m
                    mpk, mqk = m[p, k], m[q, k]
                    m[p, k] = c * mpk - s * mqk
                    m[q, k] = s * mpk + c * mqk
                for k in range(3):
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq


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
    cov = np.empty((3, 3))
    vec = np.empty((3, 3))
    mean = np.empty(3)
    for j in range(m):
        qi = query[j]
        qx, qy, qz = xyz[qi, 0], xyz[qi, 1], xyz[qi, 2]
        count = 0
        for t in range(neighbours.shape[1]):
            if neighbours[j, t] < n:
                count += 1
        if count < min_neighbours:
            continue
        mean[:] = 0.0
        cov[:, :] = 0.0
        for t in range(neighbours.shape[1]):
            i = neighbours[j, t]
            if i >= n:
                continue
            off0 = xyz[i, 0] - qx
            off1 = xyz[i, 1] - qy
            off2 = xyz[i, 2] - qz
            mean[0] += off0
            mean[1] += off1
            mean[2] += off2
            cov[0, 0] += off0 * off0
            cov[0, 1] += off0 * off1
            cov[0, 2] += off0 * off2
            cov[1, 1] += off1 * off1
            cov[1, 2] += off1 * off2
            cov[2, 2] += off2 * off2
        for a in range(3):
            mean[a] /= count
        for a in range(3):
            for b2 in range(a, 3):
                cov[a, b2] = cov[a, b2] / count - mean[a] * mean[b2]
                cov[b2, a] = cov[a, b2]
        _jacobi_eigen(cov, vec)
        lo = 0
        hi = 0
        for a in range(1, 3):
            if cov[a, a] < cov[lo, lo]:
                lo = a
            if cov[a, a] >= cov[hi, hi]:
                hi = a
        mid = 3 - lo - hi if lo != hi else (lo + 1) % 3
        if cov[mid, mid] < min_planarity * max(cov[hi, hi], 1e-300):
            continue
        nx, ny, nz = vec[0, lo], vec[1, lo], vec[2, lo]
        norm = math.sqrt(nx * nx + ny * ny + nz * nz) * math.sqrt(qx * qx + qy * qy + qz * qz)
        if norm > 0.0:
            cos[j] = min(abs(nx * qx + ny * qy + nz * qz) / norm, 1.0)
        found[j] = True
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
