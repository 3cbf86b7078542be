"""k-NN normals against the brute force on a real SemanticKITTI frame."""

from __future__ import annotations

import numpy as np

from lads.physics.knn_normals import neighbour_cos
from tests.unit.test_knn_normals import RULES, _reference


def test_matches_the_brute_force_on_a_real_kitti_frame(kitti_frame):
    xyz = kitti_frame(0)[0].astype(np.float64)
    query = np.random.default_rng(0).choice(len(xyz), 150, replace=False)
    cos, found = neighbour_cos(xyz, query, **RULES)
    ref_cos, ref_found = _reference(xyz, query)
    np.testing.assert_array_equal(found, ref_found)
    np.testing.assert_allclose(cos[found], ref_cos[found], atol=1e-9)
