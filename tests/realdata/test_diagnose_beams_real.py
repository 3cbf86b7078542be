"""Beam tables of `lads diagnose` on the real SemanticKITTI and nuScenes samples."""

from __future__ import annotations

import time

import numpy as np

from lads.diagnose.data.beams import paired_table
from lads.diagnose.data.trees import open_trees
from tests.unit.test_diagnose_beams import check_contract


def test_real_semantickitti_paired_with_itself(shared_data):
    root = shared_data / "semantickitti"
    pair = open_trees(root, root, "semantickitti", paired=True)
    start = time.perf_counter()
    table = paired_table(pair)
    seconds = time.perf_counter() - start
    check_contract(table)
    assert len(pair.sim_scans) == 3
    assert len(table) == 124_668 + 124_605 + 124_478
    assert table.ret_real.all() and (table.real_index == table.sim_index).all()
    assert np.bincount(table.scan).tolist() == [124_668, 124_605, 124_478]
    assert 0.3 < table.is_ground.mean() < 0.8
    assert np.median(np.abs(table.height_m[table.is_ground])) < 0.1
    assert table.normal_ok.mean() > 0.9
    assert set(np.unique(table.ring).tolist()) <= set(range(64))
    assert table.class_names[40] == "road"
    assert seconds < 30.0  # the target is 10 s on one core; the margin absorbs a busy machine


def test_real_nuscenes_dataroot_is_read_with_its_tables(shared_data, tmp_path):
    from tests import trees

    root = trees.real_nuscenes(tmp_path / "nusc")
    pair = open_trees(root, root, "nuscenes", paired=True)
    assert pair.sensor.label_set == "nuscenes" and pair.sensor.calibrated
    table = paired_table(pair)
    check_contract(table)
    assert table.ret_real.all()
    for s in range(len(pair.sim_scans)):  # one-to-one; coincident ego returns may swap
        rows = table.scan == s
        assert sorted(table.real_index[rows]) == sorted(table.sim_index[rows])
    assert (table.real_index == table.sim_index).mean() > 0.9
    assert (table.is_ground == np.isin(table.class_id, [24, 25, 26, 27])).all()
    assert table.class_names[24] == "flat.driveable_surface"
    full = table.scan == pair.sim_scans.index(trees.NUSC_FULL_SAMPLE)
    points = np.fromfile(root / trees.NUSC_FULL_SAMPLE, dtype="<f4").reshape(-1, 5)
    beyond = np.linalg.norm(points[:, :3].astype(np.float64), axis=1) >= 1.0  # HDL-32E R1
    assert 0.2 < 1.0 - beyond.mean() < 0.3  # ego-vehicle returns within 1 m are left out
    assert sorted(table.sim_index[full]) == np.flatnonzero(beyond).tolist()
    assert (table.range_m >= 1.0).all()
    expected = np.bincount(points[beyond, 4].astype(np.int64), minlength=32)
    assert np.bincount(table.ring[full], minlength=32).tolist() == expected.tolist()
