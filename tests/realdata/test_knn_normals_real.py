"""k-NN normals on real frames: against the brute force, and byte for byte against k-d trees."""

from __future__ import annotations

import numpy as np
import pytest
from pykdtree.kdtree import KDTree
from scipy.spatial import cKDTree

from lads.physics import knn_normals, sphere_knn
from lads.physics.modalities import IncidenceSource, incidence
from lads.physics.projection import checked_xyz
from lads.sensors.profile import load_profile
from tests.trees import NUSC_FULL_SAMPLE
from tests.unit.test_knn_normals import RULES, _reference
from tests.unit.test_sphere_knn import assert_exact


def test_matches_the_brute_force_on_a_real_kitti_frame(kitti_frame):
    xyz = kitti_frame(0)[0].astype(np.float64)
    query = np.random.default_rng(0).choice(len(xyz), 150, replace=False)
    cos, found = knn_normals.neighbour_cos(xyz, query, **RULES)
    ref_cos, ref_found = _reference(xyz, query)
    np.testing.assert_array_equal(found, ref_found)
    np.testing.assert_allclose(cos[found], ref_cos[found], atol=1e-9)
    assert_exact(xyz, query)  # the neighbours themselves, distances bit for bit


def _tree_knn(tree: str):
    """`knn_within` answered by pykdtree or scipy's cKDTree (the searches it replaced)."""

    def knn_within(xyz, query, *, k, radius_m):
        if tree == "pykdtree":
            index = KDTree(xyz, leafsize=32)
        else:
            index = cKDTree(xyz)
        _, idx = index.query(xyz[query], k=k, distance_upper_bound=radius_m)
        return np.minimum(np.asarray(idx, dtype=np.int64).reshape(len(query), k), len(xyz)), None

    return knn_within


def _frames(shared_data, kitti_frame):
    """(name, float32 xyz, profile) of real frames of all three sensors."""
    for i in range(3):
        yield f"kitti {i}", kitti_frame(i)[0], load_profile("hdl64e")
    nusc = np.fromfile(shared_data / "nuscenes" / NUSC_FULL_SAMPLE, "<f4").reshape(-1, 5)
    yield "nuscenes", np.ascontiguousarray(nusc[:, :3]), load_profile("hdl32e")
    wads = shared_data / "wads" / "sequences" / "36" / "velodyne" / "042223.bin"
    yield "wads", np.fromfile(wads, "<f4").reshape(-1, 4)[:, :3].copy(), load_profile("wads64")


@pytest.mark.parametrize("grid_only", [False, True], ids=["as-shipped", "grid-only"])
def test_the_incidence_of_real_frames_is_the_same_with_either_k_d_tree(
    shared_data, kitti_frame, monkeypatch, grid_only
):
    """The direction grid finds the same neighbours as the k-d trees, in the same order, so
    every incidence byte is unchanged; grid-only keeps even the dense nuScenes and snowy WADS
    scans, which the shipped search hands to pykdtree, on the grid."""
    if grid_only:
        monkeypatch.setattr(sphere_knn, "WORK_PER_QUERY", 10**15)
    for name, xyz, profile in _frames(shared_data, kitti_frame):
        ours = incidence(xyz, profile)
        assert (ours.source == IncidenceSource.NEIGHBOURS).sum() > 1000, name
        for tree in ("pykdtree", "scipy"):
            with monkeypatch.context() as m:
                m.setattr(knn_normals, "knn_within", _tree_knn(tree))
                theirs = incidence(xyz, profile)
            np.testing.assert_array_equal(ours.cos, theirs.cos, err_msg=f"{name} vs {tree}")
            np.testing.assert_array_equal(ours.source, theirs.source, err_msg=name)


def test_the_grid_alone_serves_the_kitti_frames(kitti_frame):
    """No k-d tree on a 64-beam frame: the grid stays well inside its work budget, and the
    0-3 isolated points within 2 m of the sensor (a window over 30 deg) that it leaves are
    compared with the few dozen points within 3 m."""
    profile = load_profile("hdl64e")
    for i in range(3):
        xyz64, _ = checked_xyz(kitti_frame(i)[0])
        query = np.flatnonzero(incidence(xyz64, profile).source != IncidenceSource.IMAGE)
        limits = sphere_knn.WORK_PER_QUERY, sphere_knn.WORK_ALLOWANCE
        pending, stop = sphere_knn._knn_grid(xyz64, query, 10, 1.0, *limits, 0)[3:]
        assert stop == len(query) and len(pending) <= 3  # near_pairs 0: all near ones listed
        pending, stop = sphere_knn._knn_grid(xyz64, query, 10, 1.0, *limits, 10**6)[3:]
        assert stop == len(query) and len(pending) == 0
