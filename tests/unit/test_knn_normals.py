"""The neighbour-PCA incidence of points without an image normal (lads.physics.knn_normals).

Specification: the k nearest points within the radius (the query itself included), their
covariance's smallest-eigenvalue direction as the normal, |cos| against the query's ray;
too few neighbours or a line-like patch is "not found".
"""

from __future__ import annotations

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


def _eigh_plane_cos(xyz, query, neighbours, min_neighbours, min_planarity):
    """`_plane_cos` by numpy's eigh on the same neighbours (the LAPACK reference)."""
    n = len(xyz)
    cos = np.zeros(len(query))
    found = np.zeros(len(query), dtype=bool)
    for j, qi in enumerate(query):
        near = neighbours[j][neighbours[j] < n]
        if len(near) < min_neighbours:
            continue
        values, vectors = np.linalg.eigh(np.cov(xyz[near].T, bias=True))
        if values[1] < min_planarity * max(values[2], 1e-300):
            continue
        cos[j] = abs(vectors[:, 0] @ xyz[qi]) / np.linalg.norm(xyz[qi])
        found[j] = True
    return cos, found


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_closed_form_eigen_solution_matches_lapack(seed):
    """The plane fit's closed-form eigenproblem against numpy's eigh, on ground, walls,
    scattered points, lines and repeated points, for several neighbour and planarity rules."""
    xyz = np.concatenate([_cloud(seed), _cloud(seed)[:200]])
    query = np.random.default_rng(seed).choice(len(xyz), 1500, replace=False).astype(np.int64)
    idx, _ = knn_within(xyz, query, k=10, radius_m=1.0)
    for min_n, planarity in [(5, 0.02), (3, 0.05), (1, 0.5)]:
        cos, found = _plane_cos(xyz, query, idx, min_n, planarity)
        ref_cos, ref_found = _eigh_plane_cos(xyz, query, idx, min_n, planarity)
        np.testing.assert_array_equal(found, ref_found)
        np.testing.assert_allclose(cos[found], ref_cos[found], atol=1e-9)
        assert found.any() and not found.all()


def test_a_patch_without_a_preferred_direction_is_not_found():
    """Repeated points (a zero covariance) and a patch whose covariance is a multiple of the
    identity have no plane: not found (where eigh would hand back an arbitrary axis)."""
    octahedron = np.array(
        [[10.0, 0, 0], [10.5, 0, 0], [9.5, 0, 0], [10, 0.5, 0], [10, -0.5, 0], [10, 0, 0.5],
         [10, 0, -0.5]]
    )  # fmt: skip
    repeated = np.full((6, 3), [0.0, 20.0, 1.0])
    xyz = np.concatenate([octahedron, repeated])
    query = np.array([0, 7], dtype=np.int64)
    idx, _ = knn_within(xyz, query, k=10, radius_m=1.0)
    cos, found = _plane_cos(xyz, query, idx, 5, 0.02)
    np.testing.assert_array_equal(found, [False, False])
    np.testing.assert_array_equal(cos, [0.0, 0.0])
