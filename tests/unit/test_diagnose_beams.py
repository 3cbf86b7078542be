"""Beam tables from two dataset trees (`lads.diagnose.data.trees`, `.beams`, `.pairing`).

The synthetic scene is ray-cast on the HDL-64E channel elevations, one ray per range-image
column over a +-16 deg sector: a flat road 1.73 m below the sensor (class 40), a 4 m wide
wall at x = 10 m (class 50, instance 7) and a back wall at x = 30 m (class 52). The wall's
left and right borders are the only range jumps near it (10 m -> 30 m).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lads.diagnose.data.beams import (
    SCAN_GROUP_STRIDE,
    cloud_features,
    paired_table,
    unpaired_tables,
)
from lads.diagnose.data.minrange import pairs_beyond_min_range
from lads.diagnose.data.pairing import pair_points
from lads.diagnose.data.table import EDGE_CAP_BEAMS, GROUP_TILE_M, ROW_FIELDS, BeamTable
from lads.diagnose.data.trees import Scan, open_trees
from lads.errors import ConfigError, DiagnoseError
from lads.sensors.profile import load_profile

HDL64 = load_profile("hdl64e")
SENSOR_HEIGHT_M = 1.73
WALL_X_M, WALL_HALF_WIDTH_M, BACK_X_M = 10.0, 2.0, 30.0
ROAD, BUILDING, OTHER_STRUCTURE = 40, 50, 52
WALL_INSTANCE = 7
SCAN0, SCAN1 = "sequences/00/velodyne/000000.bin", "sequences/00/velodyne/000001.bin"
LEVELS = (np.arange(100, dtype=np.float64) * 0.01).astype(np.float32)  # KITTI 0.00..0.99
DTYPES = {
    "scan": np.int32,
    "group": np.int64,
    "ring": np.int16,
    "azimuth_deg": np.float32,
    "elevation_deg": np.float32,
    "range_m": np.float32,
    "cos_incidence": np.float32,
    "normal_ok": np.bool_,
    "class_id": np.int32,
    "is_ground": np.bool_,
    "height_m": np.float32,
    "edge_beams": np.float32,
    "edge_span_beams": np.float32,
    "i_sim": np.float32,
    "i_real": np.float32,
    "ret_sim": np.bool_,
    "ret_real": np.bool_,
    "sim_index": np.int64,
    "real_index": np.int64,
}


def scene(wall_x_m: float = WALL_X_M, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4) float32 x, y, z, remission and (N,) uint32 labels of the synthetic scene."""
    width = HDL64.range_image_width
    half = round(16.0 / 360.0 * width)
    cols = np.arange(width // 2 - half, width // 2 + half)
    az = np.pi * (1.0 - 2.0 * (cols + 0.5) / width)  # column centres of `project`
    el = np.radians(np.asarray(HDL64.elevation_deg))
    el, az = np.meshgrid(el, az, indexing="ij")
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    with np.errstate(divide="ignore"):
        t_ground = np.where(d[:, 2] < 0, -SENSOR_HEIGHT_M / d[:, 2], np.inf)
    t_wall = wall_x_m / d[:, 0]
    t_wall[np.abs(d[:, 1] * t_wall) > WALL_HALF_WIDTH_M] = np.inf
    t_back = BACK_X_M / d[:, 0]
    t = np.stack([t_ground, t_wall, t_back], axis=1)
    hit = t.argmin(axis=1)
    xyz = d * t.min(axis=1)[:, None]
    semantic = np.array([ROAD, BUILDING, OTHER_STRUCTURE], np.uint32)[hit]
    instance = np.where(hit == 1, WALL_INSTANCE, 0).astype(np.uint32)
    rng = np.random.default_rng(seed)
    intensity = LEVELS[rng.integers(0, 100, len(xyz))]
    points = np.column_stack([xyz.astype(np.float32), intensity])
    return points, (instance << np.uint32(16)) | semantic


def write_kitti(root: Path, scans: dict[str, tuple[np.ndarray, np.ndarray | None]]) -> Path:
    """SemanticKITTI tree: relpath -> (points (N, 4) float32, labels (N,) uint32 or None)."""
    for relpath, (points, labels) in scans.items():
        scan = root / relpath
        scan.parent.mkdir(parents=True, exist_ok=True)
        points.astype("<f4").tofile(scan)
        if labels is not None:
            label = root / relpath.replace("velodyne", "labels").replace(".bin", ".label")
            label.parent.mkdir(parents=True, exist_ok=True)
            labels.astype("<u4").tofile(label)
    return root


def two_scans(labelled: bool = True) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    p0, l0 = scene()
    p1, l1 = scene(wall_x_m=12.0, seed=1)
    return {SCAN0: (p0, l0 if labelled else None), SCAN1: (p1, l1 if labelled else None)}


def check_contract(table: BeamTable) -> None:
    assert set(DTYPES) == set(ROW_FIELDS)
    for name, dtype in DTYPES.items():
        column = getattr(table, name)
        assert column.dtype == dtype, name
        assert column.shape == (len(table),), name
    assert np.isnan(table.i_sim).tolist() == (~table.ret_sim).tolist()
    assert np.isnan(table.i_real).tolist() == (~table.ret_real).tolist()
    assert ((table.sim_index >= 0) == table.ret_sim).all()
    assert ((table.real_index >= 0) == table.ret_real).all()
    assert ((table.azimuth_deg >= 0) & (table.azimuth_deg < 360)).all()
    assert ((table.cos_incidence >= 0) & (table.cos_incidence <= 1)).all()
    assert ((table.edge_beams >= 0) & (table.edge_beams <= EDGE_CAP_BEAMS)).all()


@pytest.fixture
def sim_tree(tmp_path: Path) -> Path:
    return write_kitti(tmp_path / "sim", two_scans())


# Pairing -----------------------------------------------------------------------------------


def test_identical_trees_pair_every_point_one_to_one(sim_tree, tmp_path):
    real = write_kitti(tmp_path / "real", two_scans())
    pair = open_trees(sim_tree, real, "semantickitti", paired=True)
    table = paired_table(pair)
    check_contract(table)
    points0, _ = scene()
    assert table.scans == (SCAN0, SCAN1)
    assert len(table) == len(points0) + len(scene(12.0)[0])
    assert table.ret_sim.all() and table.ret_real.all()
    assert (table.real_index == table.sim_index).all()
    first = table.scan == 0
    assert (table.i_real[first] == points0[table.real_index[first], 3]).all()
    assert (table.i_sim == table.i_real).all()
    assert table.meta == {"mode": "paired", "max_pair_distance_m": 0.15, "min_range_m": 0.9}


def test_zero_range_points_are_dropped_but_file_rows_kept(tmp_path):
    points, labels = scene()
    zero_rows = [5, 100]
    for row in zero_rows:
        points = np.insert(points, row, 0.0, axis=0)
        labels = np.insert(labels, row, 0)
    tree = write_kitti(tmp_path / "t", {SCAN0: (points, labels)})
    table = paired_table(open_trees(tree, tree, "semantickitti", paired=True))
    assert len(table) == len(points) - 2
    assert not np.isin(table.sim_index, zero_rows).any()
    in_file = np.linalg.norm(points[table.sim_index, :3].astype(np.float64), axis=1)
    np.testing.assert_allclose(table.range_m, in_file, rtol=1e-6)
    assert (table.class_id == (labels[table.sim_index] & 0xFFFF)).all()


def along_ray(points: np.ndarray, rows: np.ndarray, range_m: float) -> np.ndarray:
    """`points` with rows `rows` moved along their beams to `range_m`: same ring and azimuth,
    so the file stays stored ring by ring."""
    out = points.copy()
    xyz = out[rows, :3].astype(np.float64)
    out[rows, :3] = xyz / np.linalg.norm(xyz, axis=1, keepdims=True) * range_m
    return out


def test_points_nearer_than_the_minimum_range_leave_both_trees_paired(tmp_path):
    """HDL-64E min_range_m = 0.9 m. Ego returns at 0.3 m in both trees, a pair straddling the
    cut each way (sim 0.85 / real 0.95 m and sim 0.95 / real 0.85 m, 0.1 m apart, so paired)
    and a control pair at 0.95 m in both: only the control stays, and every kept sim row
    keeps its own real twin."""
    points, labels = scene()
    n_az = len(points) // HDL64.channels

    def row(ring: int, col: int) -> int:
        return ring * n_az + col

    ego = np.arange(row(0, 0), row(2, 0), 3)  # rings 0 and 1: every third beam
    straddle_a, straddle_b, control = row(10, 91), row(60, 170), row(40, 10)
    sim = along_ray(points, ego, 0.3)
    real = sim.copy()
    sim = along_ray(along_ray(sim, np.array([straddle_a]), 0.85), np.array([straddle_b]), 0.95)
    real = along_ray(along_ray(real, np.array([straddle_a]), 0.95), np.array([straddle_b]), 0.85)
    sim, real = (along_ray(p, np.array([control]), 0.95) for p in (sim, real))
    sim_root = write_kitti(tmp_path / "sim", {SCAN0: (sim, labels)})
    real_root = write_kitti(tmp_path / "real", {SCAN0: (real, labels)})
    pair = open_trees(sim_root, real_root, "semantickitti", paired=True)
    assert pair.profile.min_range_m == 0.9

    table = paired_table(pair)
    check_contract(table)
    dropped = np.concatenate([ego, [straddle_a, straddle_b]])
    assert len(table) == len(points) - dropped.size
    assert not np.isin(table.sim_index, dropped).any()
    assert not np.isin(table.real_index, dropped).any()
    assert table.ret_sim.all() and table.ret_real.all()  # no spurious dropped or extra beams
    assert (table.real_index == table.sim_index).all()  # still paired row for row
    assert (table.range_m >= 0.9).all()
    assert control in table.sim_index
    # rings come from the whole file's scan order, before the near points were dropped
    assert (table.ring == table.sim_index // n_az).all()
    assert table.meta["min_range_m"] == 0.9

    sim_table, real_table = unpaired_tables(pair)
    assert set(range(len(points))) - set(sim_table.sim_index) == {*ego, straddle_a}
    assert set(range(len(points))) - set(real_table.real_index) == {*ego, straddle_b}
    assert (sim_table.ring == sim_table.sim_index // n_az).all()
    assert (sim_table.range_m >= 0.9).all() and (real_table.range_m >= 0.9).all()


def test_nuscenes_returns_within_one_metre_are_dropped_with_their_ring_column(tmp_path):
    tree = write_nuscenes(tmp_path / "nusc")
    path = next(tree.rglob("*.pcd.bin"))
    points = np.fromfile(path, dtype="<f4").reshape(-1, 5)
    near = np.arange(0, len(points), 7)
    points[near, :4] = along_ray(points[:, :4], near, 0.6)[near]
    points.tofile(path)
    pair = open_trees(tree, tree, "nuscenes", paired=True)
    assert pair.profile.min_range_m == 1.0
    table = paired_table(pair)
    check_contract(table)
    assert len(table) == len(points) - near.size
    assert not np.isin(table.sim_index, near).any()
    assert table.ret_real.all() and (table.real_index == table.sim_index).all()
    assert (table.ring == points[table.sim_index, 4]).all()


def test_pairs_beyond_min_range_drop_near_points_with_their_partners():
    def scan(range_m: list[float]) -> Scan:
        xyz = np.column_stack([range_m, np.zeros((len(range_m), 2))])
        n = len(range_m)
        return Scan("s", xyz, np.zeros(n, np.float32), None, None, np.arange(n) + 10)

    sim, real = scan([0.5, 0.95, 2.0, 1.1, 3.0]), scan([0.95, 1.05, 2.0, 0.4, 5.0])
    # both near; sim near, real beyond; both beyond; sim beyond, real near; sim unpaired
    partner = np.array([3, 1, 2, 0, -1])
    kept_sim, kept_real, kept_partner = pairs_beyond_min_range(sim, real, partner, 1.0)
    assert kept_sim.index.tolist() == [12, 14]  # file rows (index + 10) of sim 2 and 4
    assert kept_real.index.tolist() == [12, 14]  # real 1 left with its near partner
    assert kept_partner.tolist() == [0, -1]  # sim 2 -> real 2, now the first kept real
    out = pairs_beyond_min_range(sim, scan([]), np.full(5, -1), 1.0)
    assert out[0].index.tolist() == [12, 13, 14] and len(out[1]) == 0
    assert out[2].tolist() == [-1, -1, -1]


def test_real_tree_missing_ten_percent_drops_exactly_those_beams(sim_tree, tmp_path):
    scans = two_scans()
    points, labels = scans[SCAN0]
    rng = np.random.default_rng(3)
    removed = np.sort(rng.choice(len(points), len(points) // 10, replace=False))
    kept = np.setdiff1d(np.arange(len(points)), removed)
    scans[SCAN0] = (points[kept], labels[kept])
    real = write_kitti(tmp_path / "real", scans)
    table = paired_table(open_trees(sim_tree, real, "semantickitti", paired=True))
    check_contract(table)
    rows = table.take(table.scan == 0)
    assert rows.ret_sim.all()  # no real-only rows: every real point has its sim twin
    assert set(rows.sim_index[~rows.ret_real]) == set(removed)
    paired = rows.ret_real
    assert (kept[rows.real_index[paired]] == rows.sim_index[paired]).all()
    assert (rows.i_real[paired] == rows.i_sim[paired]).all()
    assert table.take(table.scan == 1).ret_real.all()


def test_extra_real_points_are_real_only_rows(sim_tree, tmp_path):
    scans = two_scans()
    points, labels = scans[SCAN0]
    rng = np.random.default_rng(4)
    n_extra = 200
    flakes = np.column_stack(  # in mid-air between the sensor and the wall: far from surfaces
        [
            rng.uniform(2, 8, n_extra),
            rng.uniform(-1, 1, n_extra),
            rng.uniform(-0.5, 0.5, n_extra),
            LEVELS[rng.integers(0, 100, n_extra)],
        ]
    ).astype(np.float32)
    scans[SCAN0] = (np.vstack([points, flakes]), np.concatenate([labels, np.full(n_extra, 1)]))
    real = write_kitti(tmp_path / "real", scans)
    table = paired_table(open_trees(sim_tree, real, "semantickitti", paired=True))
    check_contract(table)
    extra = table.take(~table.ret_sim)
    assert (extra.scan == 0).all()
    assert extra.real_index.tolist() == list(range(len(points), len(points) + n_extra))
    assert (extra.sim_index == -1).all() and np.isnan(extra.i_sim).all()
    assert (extra.i_real == flakes[:, 3]).all()
    np.testing.assert_allclose(extra.range_m, np.linalg.norm(flakes[:, :3], axis=1), rtol=1e-6)
    assert (extra.class_id == 1).all()
    assert table.take(table.ret_sim).ret_real.all()


def test_pair_points_nearest_claim_wins_and_duplicates_pair_one_to_one():
    real = np.array([[0.0, 0, 0], [5.0, 0, 0]])
    sim = np.array([[0.1, 0, 0], [0.05, 0, 0], [5.0, 0, 0], [9.0, 0, 0]])
    assert pair_points(sim, real, 0.15).tolist() == [-1, 0, 1, -1]
    dup = np.repeat([[1.0, 2.0, 3.0]], 10, axis=0)  # more coincident points than candidates
    partner = pair_points(dup, dup.copy(), 0.15)
    assert sorted(partner.tolist()) == list(range(10))
    assert pair_points(sim, np.zeros((0, 3)), 0.15).tolist() == [-1] * 4


def test_unpaired_tables_hold_every_return_of_each_tree(sim_tree, tmp_path):
    other = {"sequences/05/velodyne/000010.bin": scene(wall_x_m=8.0)}
    real = write_kitti(tmp_path / "real", other)
    pair = open_trees(sim_tree, real, "semantickitti", paired=False)
    sim_table, real_table = unpaired_tables(pair)
    for table in (sim_table, real_table):
        check_contract(table)
    assert sim_table.scans == (SCAN0, SCAN1)
    assert real_table.scans == ("sequences/05/velodyne/000010.bin",)
    assert sim_table.ret_sim.all() and not sim_table.ret_real.any()
    assert real_table.ret_real.all() and not real_table.ret_sim.any()
    assert len(real_table) == len(other["sequences/05/velodyne/000010.bin"][0])
    assert (real_table.real_index == np.arange(len(real_table))).all()
    assert sim_table.meta["mode"] == real_table.meta["mode"] == "unpaired"
    with pytest.raises(DiagnoseError, match="unpaired"):
        paired_table(pair)


# Features ----------------------------------------------------------------------------------


def test_labelled_ground_is_by_class_and_instance_bits_are_removed(sim_tree):
    table = paired_table(open_trees(sim_tree, sim_tree, "semantickitti", paired=True))
    assert set(np.unique(table.class_id)) == {ROAD, BUILDING, OTHER_STRUCTURE}
    assert (table.is_ground == (table.class_id == ROAD)).all()
    assert table.class_names[ROAD] == "road" and table.class_names[BUILDING] == "building"
    road = table.is_ground
    np.testing.assert_allclose(table.height_m[road], 0.0, atol=1e-3)
    assert table.sensor.label_set == "semantickitti"


def test_unlabelled_ground_is_near_the_fitted_plane(tmp_path):
    points, labels = scene()
    tree = write_kitti(tmp_path / "t", {SCAN0: (points, None)})
    table = paired_table(open_trees(tree, tree, "semantickitti", paired=True))
    assert table.sensor.label_set is None and table.class_names == {}
    assert (table.class_id == -1).all()
    road = (labels & 0xFFFF)[table.sim_index] == ROAD
    np.testing.assert_allclose(
        table.height_m, points[table.sim_index, 2] + SENSOR_HEIGHT_M, atol=0.01
    )
    assert table.is_ground[road].all()
    assert not table.is_ground[~road & (table.height_m > 0.3)].any()


def test_only_real_labels_give_paired_rows_their_class(tmp_path):
    points, labels = scene()
    sim = write_kitti(tmp_path / "sim", {SCAN0: (points, None)})
    real = write_kitti(tmp_path / "real", {SCAN0: (points, labels)})
    table = paired_table(open_trees(sim, real, "semantickitti", paired=True))
    assert table.sensor.label_set == "semantickitti"
    assert (table.class_id == (labels & 0xFFFF)[table.real_index]).all()
    assert (table.is_ground == (table.class_id == ROAD)).all()


def test_group_ids_are_scan_and_ground_tile(sim_tree):
    table = paired_table(open_trees(sim_tree, sim_tree, "semantickitti", paired=True))
    groups = [set(np.unique(table.group[table.scan == s]).tolist()) for s in (0, 1)]
    assert groups[0] and groups[1] and not groups[0] & groups[1]
    assert (table.group >= 0).all()
    assert (table.group // SCAN_GROUP_STRIDE == table.scan).all()
    points, _ = scene()
    rows = table.scan == 0
    xy = points[table.sim_index[rows], :2].astype(np.float64)
    tiles = np.floor(xy / GROUP_TILE_M).astype(np.int64)
    _, by_tile = np.unique(tiles, axis=0, return_inverse=True)
    _, by_group = np.unique(table.group[rows], return_inverse=True)
    assert (by_tile.ravel() == by_group).all()  # same tile <=> same group


def test_edge_beams_small_at_wall_border_and_capped_far_from_it(sim_tree):
    table = paired_table(open_trees(sim_tree, sim_tree, "semantickitti", paired=True))
    rows = table.take((table.scan == 0) & (table.class_id == BUILDING))
    y, z = scene()[0][rows.sim_index, 1], scene()[0][rows.sim_index, 2]
    border, middle = np.abs(y) > WALL_HALF_WIDTH_M - 0.05, np.abs(y) < 1.0
    # At its foot the wall's side meets the road at the same range: no depth edge there.
    raised = z > -SENSOR_HEIGHT_M + 0.5
    assert (border & raised).sum() > 40 and middle.sum() > 1000
    assert (rows.edge_beams[border & raised] <= 2.0).all()
    assert (rows.edge_beams[middle] == EDGE_CAP_BEAMS).all()
    # the wall faces the sensor: well-conditioned image normals, incidence ~ cos(azimuth)
    assert rows.normal_ok.mean() > 0.95


def test_ring_from_elevation_matches_the_ray_grid(sim_tree):
    pair = open_trees(sim_tree, sim_tree, "semantickitti", paired=True)
    scan = pair.read_scan("sim", SCAN0)
    feats = cloud_features(scan, pair.profile, None, 0)
    n_az = len(scan) // HDL64.channels
    assert (feats.ring == np.repeat(np.arange(HDL64.channels), n_az)).all()
    np.testing.assert_allclose(feats.elevation_deg, np.repeat(HDL64.elevation_deg, n_az), atol=1e-3)


# Trees and errors --------------------------------------------------------------------------


def test_sensor_info_per_source(sim_tree, tmp_path):
    kitti = open_trees(sim_tree, sim_tree, "semantickitti", paired=True).sensor
    assert (kitti.profile, kitti.n_rings, kitti.encoding_kind) == ("hdl64e", 64, "unit")
    assert (kitti.step, kitti.max_value, kitti.calibrated) == (0.01, 0.99, False)
    assert not kitti.has_ring_column
    wads_points, wads_labels = scene()
    wads_points[:, 3] = np.rint(wads_points[:, 3] * 255)
    wads = write_kitti(
        tmp_path / "wads", {"sequences/36/velodyne/000001.bin": (wads_points, wads_labels)}
    )
    info = open_trees(wads, wads, "wads", paired=True).sensor
    assert (info.profile, info.encoding_kind, info.label_set) == ("wads64", "byte", "wads")


def write_nuscenes(root: Path, ring_offset: float = 0.0, n_rings: int = 32) -> Path:
    hdl32 = load_profile("hdl32e")
    el = np.radians(np.asarray(hdl32.elevation_deg))[:n_rings]
    az = np.radians(np.arange(0, 360, 0.5))
    el, az = np.meshgrid(el, az, indexing="ij")
    rng_m = np.where(el < 0, -1.84 / np.sin(np.minimum(el, -1e-3)), 20.0).clip(max=20.0)
    xyz = (
        np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
        * rng_m[..., None]
    )
    ring = np.repeat(np.arange(n_rings), az.shape[1]) + ring_offset
    intensity = np.random.default_rng(0).integers(0, 256, ring.size)
    points = np.column_stack([xyz.reshape(-1, 3), intensity, ring]).astype("<f4")
    path = root / "samples/LIDAR_TOP/log__LIDAR_TOP__1.pcd.bin"
    path.parent.mkdir(parents=True)
    points.tofile(path)
    return root


def test_bare_nuscenes_scans_use_their_ring_column(tmp_path):
    tree = write_nuscenes(tmp_path / "nusc")
    pair = open_trees(tree, tree, "nuscenes", paired=True)
    assert pair.sim_scans == ("samples/LIDAR_TOP/log__LIDAR_TOP__1.pcd.bin",)
    info = pair.sensor
    assert (info.profile, info.calibrated, info.has_ring_column) == ("hdl32e", True, True)
    assert info.label_set is None
    table = paired_table(pair)
    check_contract(table)
    assert table.ret_real.all()
    assert (table.ring == np.repeat(np.arange(32), 720)[table.sim_index]).all()


def test_invalid_ring_column_reads_as_another_sensor(tmp_path):
    good = write_nuscenes(tmp_path / "real")
    bad = write_nuscenes(tmp_path / "sim", ring_offset=0.5)
    with pytest.raises(DiagnoseError, match=r"sim tree.*'ring' column.*different sensors"):
        open_trees(bad, good, "nuscenes", paired=True)


def test_mismatched_relpaths_name_examples(sim_tree, tmp_path):
    scans = two_scans()
    scans["sequences/00/velodyne/000002.bin"] = scans.pop(SCAN1)
    real = write_kitti(tmp_path / "real", scans)
    with pytest.raises(DiagnoseError, match=r"000001\.bin.*000002\.bin"):
        open_trees(sim_tree, real, "semantickitti", paired=True)
    unpaired = open_trees(sim_tree, real, "semantickitti", paired=False)
    assert unpaired.real_scans[-1].endswith("000002.bin")


def test_missing_or_empty_roots_raise(sim_tree, tmp_path):
    with pytest.raises(DiagnoseError, match="does not exist"):
        open_trees(sim_tree, tmp_path / "nowhere", "semantickitti", paired=True)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DiagnoseError, match="real tree holds no semantickitti scans"):
        open_trees(sim_tree, tmp_path / "empty", "semantickitti", paired=True)
    with pytest.raises(DiagnoseError, match="no nuscenes scans.*v1.0-\\* table folder"):
        open_trees(tmp_path / "empty", tmp_path / "empty", "nuscenes", paired=True)
    with pytest.raises(ConfigError, match="voxelscape"):
        open_trees(sim_tree, sim_tree, "voxelscape", paired=True)


def test_byte_intensities_in_a_kitti_tree_are_another_sensor(sim_tree, tmp_path):
    scans = two_scans()
    points, labels = scans[SCAN0]
    points = points.copy()
    points[:, 3] = np.rint(points[:, 3] * 255)
    scans[SCAN0] = (points, labels)
    real = write_kitti(tmp_path / "real", scans)
    with pytest.raises(DiagnoseError, match=r"real/sequences/00/velodyne/000000\.bin.*real tree"):
        open_trees(sim_tree, real, "semantickitti", paired=True)


def test_five_column_scans_in_a_kitti_tree_are_another_sensor(sim_tree, tmp_path):
    points, _ = scene()
    # 1003 rows: 20 * 1003 bytes divide into 5 float32 columns only (not 3, 4, 6, 7 or 8)
    five = np.column_stack([points, np.zeros(len(points), np.float32)])[:1003]
    real = write_kitti(tmp_path / "real", {SCAN0: (five, None), SCAN1: two_scans()[SCAN1]})
    with pytest.raises(DiagnoseError, match=r"000000\.bin: .* 4-column .* fit \[5\] columns"):
        open_trees(sim_tree, real, "semantickitti", paired=True)


def test_a_unit_encoded_tree_beside_a_byte_encoded_one_is_refused(sim_tree, tmp_path):
    """WADS (0-255) against a tree written for SemanticKITTI's 0-1 remission: each tree fits
    the byte range on its own, together they cannot be compared."""
    scans = {k: (p.copy(), lab) for k, (p, lab) in two_scans().items()}
    for points, _ in scans.values():
        points[:, 3] = np.round(points[:, 3] * 255.0)
    real = write_kitti(tmp_path / "real", scans)
    with pytest.raises(DiagnoseError, match=r"\(sim tree\): .* the values look unit-encoded"):
        open_trees(sim_tree, real, "wads", paired=True)
    open_trees(real, real, "wads", paired=True)  # the same encoding on both sides is fine


def test_unpaired_trees_with_labels_on_one_side_only_are_refused(sim_tree, tmp_path):
    bare = write_kitti(tmp_path / "bare", two_scans(labelled=False))
    with pytest.raises(DiagnoseError, match="sim tree has no label file"):
        open_trees(bare, sim_tree, "semantickitti", paired=False)
    open_trees(bare, sim_tree, "semantickitti", paired=True)  # paired beams need no classes


def test_a_report_folder_inside_a_compared_tree_is_refused(sim_tree, tmp_path):
    from lads.diagnose.run import diagnose

    real = write_kitti(tmp_path / "real", two_scans())
    for out, corrected in ((real / "diag", None), (tmp_path / "ok", sim_tree / "fixed")):
        with pytest.raises(DiagnoseError, match="lads never writes into a dataset it reads"):
            diagnose(sim_tree, real, "semantickitti", out, write_corrected_to=corrected)
        assert not out.exists() and (corrected is None or not corrected.exists())


def test_a_paired_run_where_few_beams_return_in_both_trees_warns(sim_tree):
    import dataclasses

    from lads.diagnose.run import _pairing

    table = paired_table(open_trees(sim_tree, sim_tree, "semantickitti", paired=True))
    same = _pairing(table, paired=True)
    assert same["warnings"] == [] and same["pairing"]["share_both"] == 1.0
    gone = table.ret_real.copy()
    gone[: int(0.7 * gone.size)] = False
    few = _pairing(dataclasses.replace(table, ret_real=gone), paired=True)
    assert few["pairing"]["real_only"] == 0 and few["pairing"]["sim_only"] > 0
    assert len(few["warnings"]) == 1 and "--unpaired" in few["warnings"][0]
    assert _pairing(table, paired=False) == {"warnings": []}


def test_a_one_sided_scan_mismatch_names_only_the_side_that_lacks_scans(sim_tree, tmp_path):
    scans = two_scans()
    scans.pop(SCAN1)
    real = write_kitti(tmp_path / "real", scans)
    with pytest.raises(DiagnoseError) as err:
        open_trees(sim_tree, real, "semantickitti", paired=True)
    assert "1 of 2 scans of the sim tree" in str(err.value) and "e.g. []" not in str(err.value)


def test_the_summary_line_names_class_and_status():
    from lads.diagnose.command import _named

    claimed = {"id": "C6", "key": "class_reflectance", "class": "road", "status": "claimed"}
    possible = {"id": "C1", "key": "range_exponent", "class": None, "status": "possible"}
    assert _named(claimed) == "C6[road] class_reflectance"
    assert _named(possible) == "C1 range_exponent (possible)"
