"""The neighbour-PCA incidence of points without an image normal (lads.physics.knn_normals).

Specification: the k nearest points within the radius (the query itself included), their
covariance's smallest-eigenvalue direction as the normal, |cos| against the query's ray;
too few neighbours or a line-like patch is "not found".
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from lads.physics.knn_normals import _plane_cos, neighbour_cos
from lads.physics.sphere_knn import knn_within

RULES = {"k": 10, "radius_m": 1.0, "min_neighbours": 5, "min_planarity": 0.02}


def _reference(xyz, query):
    """Brute force: exact neighbours by sorting all distances, numpy eigh."""
    cos = np.zeros(len(query))
    found = np.zeros(len(query), dtype=bool)
    for j, qi in enumerate(query):
        d = np.linalg.norm(xyz - xyz[qi], axis=1)
        near = np.argsort(d, kind="stable")[: RULES["k"]]
        near = near[d[near] <= RULES["radius_m"]]
        if len(near) < RULES["min_neighbours"]:
            continue
        cov = np.cov(xyz[near].T, bias=True)
        values, vectors = np.linalg.eigh(cov)
        if values[1] < RULES["min_planarity"] * max(values[2], 1e-300):
            continue
        ray = xyz[qi]
        cos[j] = abs(vectors[:, 0] @ ray) / (np.linalg.norm(vectors[:, 0]) * np.linalg.norm(ray))
        found[j] = True
    return cos, found


def _cloud(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ground = np.column_stack(
        [rng.uniform(2, 12, 3000), rng.uniform(-5, 5, 3000), -1.7 + rng.normal(0, 0.01, 3000)]
    )
    wall = np.column_stack(
        [
            np.full(1500, 8.0) + rng.normal(0, 0.01, 1500),
            rng.uniform(-5, 5, 1500),
            rng.uniform(-1.7, 1.0, 1500),
        ]
    )
    scatter = rng.uniform([-30, -30, -2], [30, 30, 3], (500, 3))
    line = np.column_stack([np.linspace(15, 16, 12), np.zeros(12), np.zeros(12)])
    return np.concatenate([ground, wall, scatter, line])


@pytest.mark.parametrize("seed", [0, 1])
def test_matches_a_brute_force_neighbour_pca(seed):
    xyz = _cloud(seed)
    query = np.random.default_rng(seed).choice(len(xyz), 400, replace=False)
    query = np.concatenate([query, np.arange(len(xyz) - 12, len(xyz))])
    cos, found = neighbour_cos(xyz, query, **RULES)
    ref_cos, ref_found = _reference(xyz, query)
    np.testing.assert_array_equal(found, ref_found)
    np.testing.assert_allclose(cos[found], ref_cos[found], atol=1e-9)
    assert found.any() and not found.all()


def test_a_flat_patch_gives_the_analytic_cosine_and_a_line_or_lone_point_is_not_found():
    rng = np.random.default_rng(3)
    ground = np.column_stack([rng.uniform(9, 11, 2000), rng.uniform(-1, 1, 2000),
                              np.full(2000, -2.0)])  # fmt: skip
    line = np.column_stack([np.linspace(20, 20.9, 10), np.zeros(10), np.zeros(10)])
    lone = np.array([[0.0, 40.0, 0.0]])
    xyz = np.concatenate([ground, line, lone])
    query = np.array([0, 1, 2000, len(xyz) - 1])
    cos, found = neighbour_cos(xyz, query, **RULES)
    np.testing.assert_array_equal(found, [True, True, False, False])
    expected = 2.0 / np.linalg.norm(xyz[:2], axis=1)  # normal (0, 0, 1), |z| / R
    np.testing.assert_allclose(cos[:2], expected, rtol=1e-9)


def test_empty_queries_give_empty_results():
    cos, found = neighbour_cos(np.zeros((3, 3)) + 1.0, np.array([], dtype=np.int64), **RULES)
    assert cos.shape == (0,) and found.shape == (0,)


@numba.njit
def _array_jacobi(m, v):
    """The plane fit's eigen-solver as it was, on 3 x 3 arrays (the byte reference)."""
    for a in range(3):
        for b in range(3):
            v[a, b] = 1.0 if a == b else 0.0
    for _ in range(12):
        off = m[0, 1] ** 2 + m[0, 2] ** 2 + m[1, 2] ** 2
        if off <= 1e-30 * (m[0, 0] ** 2 + m[1, 1] ** 2 + m[2, 2] ** 2) or off == 0.0:
            return
        for p in range(2):
            for q in range(p + 1, 3):
                if m[p, q] == 0.0:
                    continue
                theta = (m[q, q] - m[p, p]) / (2.0 * m[p, q])
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(3):
                    mkp, mkq = m[k, p], m[k, q]
                    m[k, p] = c * mkp - s * mkq
                    m[k, q] = s * mkp + c * mkq
                for k in range(3):
                    mpk, mqk = m[p, k], m[q, k]
                    m[p, k] = c * mpk - s * mqk
                    m[q, k] = s * mpk + c * mqk
                for k in range(3):
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq


@numba.njit
def _array_plane_cos(xyz, query, neighbours, min_neighbours, min_planarity):
    """`_plane_cos` as it was, on arrays (the byte reference)."""
    n = xyz.shape[0]
    cos = np.zeros(query.shape[0])
    found = np.zeros(query.shape[0], dtype=np.bool_)
    cov = np.empty((3, 3))
    vec = np.empty((3, 3))
    mean = np.empty(3)
    for j in range(query.shape[0]):
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
            off = (xyz[i, 0] - qx, xyz[i, 1] - qy, xyz[i, 2] - qz)
            for a in range(3):
                mean[a] += off[a]
            cov[0, 0] += off[0] * off[0]
            cov[0, 1] += off[0] * off[1]
            cov[0, 2] += off[0] * off[2]
            cov[1, 1] += off[1] * off[1]
            cov[1, 2] += off[1] * off[2]
            cov[2, 2] += off[2] * off[2]
        for a in range(3):
            mean[a] /= count
        for a in range(3):
            for b in range(a, 3):
                cov[a, b] = cov[a, b] / count - mean[a] * mean[b]
                cov[b, a] = cov[a, b]
        _array_jacobi(cov, vec)
        lo = hi = 0
        for a in range(1, 3):
            if cov[a, a] < cov[lo, lo]:
                lo = a
            if cov[a, a] >= cov[hi, hi]:
                hi = a
        mid = 3 - lo - hi if lo != hi else (lo + 1) % 3
        if cov[mid, mid] < min_planarity * max(cov[hi, hi], 1e-300):
            continue
        nx, ny, nz = vec[0, lo], vec[1, lo], vec[2, lo]
        norm = np.sqrt(nx * nx + ny * ny + nz * nz) * np.sqrt(qx * qx + qy * qy + qz * qz)
        if norm > 0.0:
            cos[j] = min(abs(nx * qx + ny * qy + nz * qz) / norm, 1.0)
        found[j] = True
    return cos, found


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_scalar_eigen_solver_gives_the_array_versions_bytes(seed):
    """The plane fit runs the Jacobi rotations on scalars in registers; same operations in the
    same order as on the arrays, so the same bytes (also for lines, duplicates, k < 5)."""
    xyz = np.concatenate([_cloud(seed), _cloud(seed)[:200], np.zeros((3, 3))])
    query = np.random.default_rng(seed).choice(len(xyz), 1500, replace=False)
    idx, _ = knn_within(xyz, query, k=10, radius_m=1.0)
    for min_n, planarity in [(5, 0.02), (3, 0.0), (1, 0.5)]:
        ours = _plane_cos(xyz, query.astype(np.int64), idx, min_n, planarity)
        ref = _array_plane_cos(xyz, query.astype(np.int64), idx, min_n, planarity)
        assert ours[0].tobytes() == ref[0].tobytes() and ours[1].tobytes() == ref[1].tobytes()
