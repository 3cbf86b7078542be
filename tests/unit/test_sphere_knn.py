"""Exact k nearest neighbours within a radius from the direction grid (lads.physics.sphere_knn).

Specification: for every query, the points at squared distance (dx^2 + dy^2 + dz^2, summed in
that order in float64) strictly below radius^2, the k nearest, in ascending distance; the
same sets as pykdtree and scipy (points at exactly equal distances may order differently, or
at the k-th place be another of the equals). Every test compares with a brute force over all
points; `grid_only` keeps the k-d tree fallbacks out, so the grid's bounds alone are tested.
"""

from __future__ import annotations

import numpy as np
import pytest
from pykdtree.kdtree import KDTree
from scipy.spatial import cKDTree

from lads.errors import ConfigError, InvalidPointsError
from lads.physics import sphere_knn
from lads.physics.sphere_knn import knn_within

K, RADIUS = 10, 1.0


@pytest.fixture
def grid_only(monkeypatch):
    """No query goes to the k-d tree for want of work: the grid serves all but the nearest."""
    monkeypatch.setattr(sphere_knn, "WORK_PER_QUERY", 10**15)


def _grid_paths(xyz, query, *, work_per_query=None, allowance=None, near_pairs=None):
    """(pending, stop) of the grid kernel: queries left to a near tree, and the position from
    which the rest of the scan went to the full tree; the shipped limits unless given."""
    out = sphere_knn._knn_grid(
        np.ascontiguousarray(xyz, dtype=np.float64),
        np.asarray(query, dtype=np.int64),
        K,
        RADIUS,
        sphere_knn.WORK_PER_QUERY if work_per_query is None else work_per_query,
        sphere_knn.WORK_ALLOWANCE if allowance is None else allowance,
        sphere_knn.NEAR_PAIRS if near_pairs is None else near_pairs,
    )
    assert out[0]
    return out[3], out[4]


def _brute(xyz, query, k=K, radius=RADIUS):
    """Per query: (indices, squared distances) of the k nearest strictly within the radius,
    ascending (ties by index), from every point's distance summed as pykdtree sums it."""
    out = []
    for qi in query:
        dx = xyz[qi, 0] - xyz[:, 0]
        dy = xyz[qi, 1] - xyz[:, 1]
        dz = xyz[qi, 2] - xyz[:, 2]
        d2 = dx * dx + dy * dy + dz * dz
        order = np.argsort(d2, kind="stable")
        order = order[d2[order] < radius * radius][:k]
        out.append((order, d2[order]))
    return out


def assert_exact(xyz, query, k=K, radius=RADIUS):
    """knn_within equals the brute force: the same squared distances bit for bit, and the
    same neighbours except among points at exactly the k-th distance."""
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    query = np.asarray(query, dtype=np.int64)
    idx, d2 = knn_within(xyz, query, k=k, radius_m=radius)
    assert idx.shape == d2.shape == (len(query), k)
    for j, (ref_i, ref_d2) in enumerate(_brute(xyz, query, k, radius)):
        n = len(ref_i)
        np.testing.assert_array_equal(d2[j, :n], ref_d2, err_msg=f"query {query[j]}")
        assert np.all(idx[j, n:] == len(xyz)) and np.all(np.isinf(d2[j, n:]))
        got = idx[j, :n]
        assert len(set(got.tolist())) == n
        q = xyz[query[j]]
        own = (q[0] - xyz[got, 0]) ** 2 + (q[1] - xyz[got, 1]) ** 2 + (q[2] - xyz[got, 2]) ** 2
        np.testing.assert_array_equal(own, d2[j, :n])  # each index at its distance
        if n:
            surely = ref_i[ref_d2 < ref_d2[-1]]  # nearer than the k-th: no tie can swap them
            assert set(surely.tolist()) <= set(got.tolist()), f"query {query[j]}"
    return idx, d2


def _scan(rng, rings=48, steps=900, elevation_deg=(-25.0, 6.0), noise=0.01):
    """A spinning-LiDAR-like scan: ground at z = -1.7, walls of a 30 x 24 m box, a pole."""
    el = np.radians(np.linspace(*elevation_deg, rings))[:, None] + rng.normal(0, 1e-4, (rings, 1))
    az = np.radians(np.arange(steps) * 360.0 / steps)[None, :] + rng.normal(0, 3e-4, (1, steps))
    el, az = np.broadcast_arrays(el, az)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ground = np.where(d[..., 2] < 0, -1.7 / d[..., 2], np.inf)
        walls = np.minimum(15.0 / np.abs(d[..., 0]), 12.0 / np.abs(d[..., 1]))
    r = np.minimum(np.minimum(ground, walls), 60.0) + rng.normal(0, noise, el.shape)
    xyz = (d * r[..., None]).reshape(-1, 3)
    pole = np.column_stack([np.full(60, 4.0), np.full(60, 2.0), np.linspace(-1.7, 3.0, 60)])
    return np.concatenate([xyz, pole + rng.normal(0, 0.02, pole.shape)])


def test_a_scan_like_cloud_is_served_by_the_grid_alone_and_exactly():
    rng = np.random.default_rng(0)
    flakes = rng.uniform(-10, 10, (40, 3))  # falling snow: isolated points in the air
    xyz = np.concatenate([_scan(rng), flakes])
    query = np.concatenate(
        [rng.choice(len(xyz) - 40, 600, replace=False), len(xyz) - 1 - np.arange(40)]
    )
    pending, stop = _grid_paths(xyz, query, near_pairs=0)
    assert len(pending) == 0 and stop == len(query)  # no k-d tree anywhere
    idx, _ = assert_exact(xyz, query)
    isolated = (idx < len(xyz)).sum(1) < K
    assert isolated.any() and not isolated.all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_points_in_a_box_around_the_sensor(grid_only, seed):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-12, 12, (4000, 3)) * rng.uniform(0.05, 1.0, (4000, 1))
    assert_exact(xyz, rng.choice(len(xyz), 400, replace=False))


def test_dense_planes_at_grazing_angles(grid_only):
    """Ground rings 0.3 deg apart seen at 2-6 deg: the rings lie ~1 m apart, a ring's points
    ~1 cm apart, so the k nearest lie along the ring and the bins above and below are empty."""
    rng = np.random.default_rng(3)
    el = np.radians(-np.linspace(2.0, 6.0, 14))[:, None]
    az = np.radians(np.linspace(-20, 20, 4000))[None, :]
    el, az = np.broadcast_arrays(el, az)
    r = 1.7 / np.sin(-el)
    xyz = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), -1.7 + 0 * az], -1)
    xyz = xyz.reshape(-1, 3)
    xyz += rng.normal(0, 1e-3, xyz.shape)
    assert_exact(xyz, rng.choice(len(xyz), 500, replace=False))


def test_points_on_and_near_the_z_axis(grid_only):
    """Straight above and below the sensor the horizontal range is 0 (any azimuth)."""
    rng = np.random.default_rng(4)
    z = np.linspace(-5, 5, 200)
    axis = np.column_stack([np.zeros(200), np.zeros(200), z])
    near = axis + np.column_stack([rng.normal(0, 1e-3, (200, 2)), np.zeros(200)])
    tiny = axis + np.column_stack([rng.normal(0, 1e-12, (200, 2)), np.zeros(200)])
    ring = np.column_stack([0.3 * np.cos(z * 7), 0.3 * np.sin(z * 7), z])
    xyz = np.concatenate([axis, near, tiny, ring, _scan(rng, rings=16, steps=300)])
    assert_exact(xyz, np.arange(800))


def test_points_at_the_origin_and_queries_near_the_sensor(grid_only):
    """Exact zero-range points, denormal ones and points within a radius of the sensor."""
    rng = np.random.default_rng(5)
    zeros = np.zeros((7, 3))
    specks = np.array([[1e-310, 0, 0], [0, -1e-300, 1e-300], [5e-324, 5e-324, 0]])
    close = rng.normal(0, 0.4, (300, 3))
    xyz = np.concatenate([zeros, specks, close, _scan(rng, rings=24, steps=400)])
    assert_exact(xyz, np.arange(310))
    assert_exact(xyz, np.arange(310), k=3, radius=0.05)


def test_duplicated_points_and_equal_distances(grid_only):
    """WADS repeats ~40 % of its rows: ties at distance 0 and at equal distances."""
    rng = np.random.default_rng(6)
    base = _scan(rng, rings=24, steps=360)
    xyz = np.concatenate([base, base[::2], base[::3], base[::2]])
    grid_pts = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0), [0.0]), -1).reshape(-1, 3)
    xyz = np.concatenate([xyz, grid_pts * 0.25 + [8.0, 3.0, -1.0]])  # equal distances
    assert_exact(xyz, np.concatenate([rng.choice(len(base), 300), len(xyz) - np.arange(1, 26)]))


def test_the_azimuth_seam_at_180_deg(grid_only):
    """Points just either side of -x (y = +-0, +-tiny): their bins sit at both grid ends."""
    rng = np.random.default_rng(7)
    n = 2000
    x = -rng.uniform(2, 20, n)
    y = rng.normal(0, 0.3, n) * rng.choice([1e-9, 1e-3, 1.0], n)
    y[:50] = 0.0
    y[50:100] = -0.0
    xyz = np.column_stack([x, y, rng.normal(-1, 0.5, n)])
    assert_exact(xyz, np.arange(0, n, 4))


def test_a_kth_neighbour_beyond_the_first_window(grid_only):
    """Nine neighbours straight behind the query, in its own bin, 5-45 cm away along the
    ray; the true 9th and 10th lie 18 and 20 cm off to the side, three bins away in azimuth
    and elevation, and must replace the farthest ones behind."""
    q = np.array([10.0, 0.0, 0.0])
    behind = q + np.outer(0.05 * np.arange(1, 10), [1.0, 0.0, 0.0])
    side = np.array([[10.0, 0.18, 0.0], [10.0, 0.0, 0.2]])
    far = _scan(np.random.default_rng(8), rings=20, steps=300)
    xyz = np.concatenate([q[None], behind, side, far])
    idx, d2 = assert_exact(xyz, [0])
    assert {10, 11} <= set(idx[0].tolist())


def test_isolated_points_and_a_lone_point(grid_only):
    rng = np.random.default_rng(9)
    sparse = rng.uniform(-40, 40, (300, 3))
    xyz = np.concatenate([sparse, [[0.0, 55.0, 0.0]], _scan(rng, rings=16, steps=300)])
    idx, _ = assert_exact(xyz, np.arange(301))
    assert idx[300, 0] == 300 and np.all(idx[300, 1:] == len(xyz))  # only itself


def test_a_point_at_exactly_the_radius_is_left_out_as_by_both_trees():
    xyz = np.array(
        [
            [10.0, 0, 0],
            [11.0, 0, 0],
            [10.0, 0.5, 0],
            [9.0, 0, 0],
            [10.0, 0, np.nextafter(1.0, 0)],
            [10.0, np.nextafter(-1.0, 0), 0],
        ]
    )
    idx, d2 = knn_within(xyz, [0], k=6, radius_m=1.0)
    dist, tree = KDTree(xyz, leafsize=32).query(xyz[:1], k=6, distance_upper_bound=1.0)
    _, scipy_tree = cKDTree(xyz).query(xyz[:1], k=6, distance_upper_bound=1.0)
    for other in (tree, scipy_tree):
        assert set(idx[0].tolist()) == set(np.asarray(other[0], dtype=np.int64).tolist())
    assert set(idx[0, :4].tolist()) == {0, 2, 4, 5} and np.all(idx[0, 4:] == 6)
    np.testing.assert_array_equal(np.sqrt(d2[0]), dist[0])  # (1.0 and 1.0 - 1 ulp)


def test_the_fallbacks_are_exact_too(monkeypatch):
    """A dense cluster at the sensor (nuScenes' ego returns) costs the grid too much: the rest
    of the scan goes to pykdtree. Queries within 2 radii that need > 30 deg are compared with
    every point within 3 radii, or, past NEAR_PAIRS pairs, searched by pykdtree on them."""
    rng = np.random.default_rng(10)
    blob = np.outer(rng.uniform(0.01, 0.2, 3000), [0.07, -1.0, -0.001])  # along one ray
    xyz = np.concatenate([blob, _scan(rng, rings=24, steps=400)])
    query = np.concatenate([np.arange(0, 3000, 3), rng.choice(len(xyz), 200)])
    assert _grid_paths(xyz, query)[1] < len(query)
    assert_exact(xyz, query)
    lonely = np.concatenate([[[0.3, 0.0, 0.0], [0.0, -0.5, 0.2]], _scan(rng, rings=24, steps=400)])
    assert len(_grid_paths(lonely, [0, 1], work_per_query=10**15, near_pairs=0)[0]) == 2
    assert len(_grid_paths(lonely, [0, 1], work_per_query=10**15)[0]) == 0  # compared with all
    assert_exact(lonely, [0, 1])
    monkeypatch.setattr(sphere_knn, "NEAR_PAIRS", 0)
    assert_exact(lonely, [0, 1])  # by the near tree


def test_empty_and_degenerate_inputs():
    xyz = _scan(np.random.default_rng(11), rings=8, steps=60)
    idx, d2 = knn_within(xyz, np.array([], dtype=np.int64), k=K, radius_m=RADIUS)
    assert idx.shape == d2.shape == (0, K)
    assert_exact(xyz[:3], [0, 1, 2])  # fewer points than k
    assert_exact(np.zeros((4, 3)), [0, 3])  # every point at the origin
    assert_exact(xyz, [5, 5, 5], k=1)  # repeated queries, k = 1


@pytest.mark.parametrize(
    ("xyz", "k", "radius", "error"),
    [
        (np.array([[np.nan, 0, 0], [1.0, 0, 0]]), 3, 1.0, InvalidPointsError),
        (np.array([[np.inf, 0, 0], [1.0, 0, 0]]), 3, 1.0, InvalidPointsError),
        (np.array([[1e200, 0, 0], [1.0, 0, 0]]), 3, 1.0, InvalidPointsError),
        (np.zeros((2, 2)), 3, 1.0, InvalidPointsError),
        (np.zeros((2, 3)), 0, 1.0, ConfigError),
        (np.zeros((2, 3)), 3, 0.0, ConfigError),
        (np.zeros((2, 3)), 3, np.inf, ConfigError),
    ],
)
def test_bad_arguments_raise_lads_errors(xyz, k, radius, error):
    with pytest.raises(error):
        knn_within(xyz, [0], k=k, radius_m=radius)


def test_points_at_the_origin_count_for_a_query_the_grid_serves(grid_only):
    """All other points straight above the sensor: the query's window covers the whole grid
    at once, so the grid serves it, and the three points at the origin are its neighbours."""
    xyz = np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0.3], [0, 0, 0.5], [0, 0, 0.9]])
    pending, stop = _grid_paths(xyz, [3], work_per_query=10**15, near_pairs=0)
    assert len(pending) == 0 and stop == 1
    idx, _ = assert_exact(xyz, [3])
    assert {0, 1, 2} <= set(idx[0].tolist())


def test_neighbours_across_the_z_axis(grid_only):
    """A query 5 cm off the z axis, 3 m up: its neighbours sit on the far side of the axis,
    180 deg away in azimuth but 10 cm away, behind a window edge more than 90 deg off."""
    rng = np.random.default_rng(12)
    query = np.array([[0.05, 0.0, 3.0]])
    across = np.column_stack(
        [np.full(21, -0.05), rng.normal(0, 0.01, 21), 3.0 + 0.01 * np.arange(-10, 11)]
    )
    same_side = np.column_stack([np.full(10, 0.05), np.zeros(10), 3.5 + 0.05 * np.arange(10)])
    xyz = np.concatenate([query, across, same_side, _scan(rng, rings=16, steps=300)])
    idx, _ = assert_exact(xyz, [0])
    assert set(idx[0, 1:].tolist()) <= set(range(1, 22))
