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


class _ScipyTree:
    """scipy's cKDTree behind the interface knn_normals uses (the tree it used before)."""

    def __init__(self, xyz, leafsize=None):  # the leaf size changes speed, not neighbours
        from scipy.spatial import cKDTree

        self.tree = cKDTree(xyz)

    def query(self, points, k, distance_upper_bound):
        return self.tree.query(points, k=k, distance_upper_bound=distance_upper_bound)


def test_the_incidence_of_real_frames_is_the_same_with_scipys_tree(kitti_frame, monkeypatch):
    """pykdtree finds the same exact neighbours as scipy, so every incidence byte of the real
    frames is unchanged by the switch (the fallback is the only user of the tree)."""
    from lads.physics import knn_normals
    from lads.physics.modalities import IncidenceSource, incidence
    from lads.sensors.profile import load_profile

    profile = load_profile("hdl64e")
    for i in range(3):
        xyz = kitti_frame(i)[0]
        ours = incidence(xyz, profile)
        with monkeypatch.context() as m:
            m.setattr(knn_normals, "KDTree", _ScipyTree)
            theirs = incidence(xyz, profile)
        assert (ours.source == IncidenceSource.NEIGHBOURS).sum() > 1000  # the fallback answered
        np.testing.assert_array_equal(ours.cos, theirs.cos)
        np.testing.assert_array_equal(ours.source, theirs.source)
