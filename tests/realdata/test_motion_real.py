"""`lads build --variant motion-recorded` on the real frames of the readers with poses: each
frame's motion is the one its sequence's poses recorded.

SemanticKITTI: every labelled frame of sequence 00, with KITTI's ground-truth poses standing
in for SemanticKITTI's own poses.txt (../shared/data/SOURCES.md) and the real times.txt;
sequence 90 has no poses, so its frames fail by name. nuScenes: the 40 labelled keyframes of
the KITTI-style export with their lidar -> global poses (ego-body returns and zero-range
placeholders included).
"""

from __future__ import annotations

import json

import numpy as np

from lads.config import pipeline_for
from lads.runner import run_build
from lads.verify import verify_tree
from tests.real_trees import KITTI_SEQ90, real_nuscenes_kitti
from tests.realdata.test_sensor_real import KITTI_GT_POSES, _kitti_tree
from tests.trees import SHARED_DATA


def _rows(out):
    rows = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    return {r["item_id"].split(":", 1)[1]: r for r in rows if "points" in r}


def test_real_kitti_frames_move_at_the_speed_their_poses_recorded(shared_data, tmp_path):
    src = _kitti_tree(tmp_path / "src")
    out = tmp_path / "out"
    pipeline = pipeline_for("semantickitti", "motion-recorded")
    report = run_build("semantickitti", src, out, pipeline, jobs=2, progress=False, figures=True)
    # sequence 90 has no poses: each of its frames fails by name, the others build
    assert len(report.failed) == len(KITTI_SEQ90)
    assert all("poses.txt" in message for _, message in report.failed)
    rows = _rows(out)
    assert len(rows) == 7
    # Independent check: a pose's translation norm difference is frame-free, so the speed is
    # |c_{k+1} - c_{k-1}| / (t_{k+1} - t_{k-1}) of the camera centres in poses.txt.
    poses = np.loadtxt(KITTI_GT_POSES).reshape(-1, 3, 4)
    times = np.loadtxt(SHARED_DATA / "semantickitti" / "sequences" / "00" / "times.txt")
    for rel, row in rows.items():
        k = int(rel.rsplit("/", 1)[1].split(".")[0])
        lo, hi = max(k - 1, 0), min(k + 1, len(poses) - 1)
        expected = np.linalg.norm(poses[hi][:, 3] - poses[lo][:, 3]) / (times[hi] - times[lo])
        assert abs(row["conditions"]["speed_m_s"] - expected) < 1e-3 * max(expected, 1.0)
        assert row["points"]["lost"] == 0
    assert max(r["conditions"]["speed_m_s"] for r in rows.values()) > 5.0  # a moving car


def test_real_kitti_motion_recorded_verifies_and_regenerates(shared_data, tmp_path):
    src = _kitti_tree(tmp_path / "src")
    out = tmp_path / "out"
    pipeline = pipeline_for("semantickitti", "motion-recorded")
    options = {"sequences": ["00"]}
    report = run_build(
        "semantickitti", src, out, pipeline, reader_options=options, jobs=1, progress=False
    )
    assert report.complete, report.failed
    check = verify_tree(out, src, regenerate=2, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]


def test_real_nuscenes_keyframes_keep_ego_body_and_empty_rows(shared_data, tmp_path):
    src = real_nuscenes_kitti(tmp_path / "src")
    out = tmp_path / "out"
    pipeline = pipeline_for("nuscenes-kitti", "motion-recorded")
    report = run_build("nuscenes-kitti", src, out, pipeline, jobs=2, progress=False, figures=False)
    assert report.complete, report.failed
    check = verify_tree(out, src, regenerate=1, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]
    rows = _rows(out)
    speeds = np.array([r["conditions"]["speed_m_s"] for r in rows.values()])
    # scene-0002's 40 keyframes cover 109 m in about 20 s
    assert 2.0 < np.median(speeds) < 12.0 and speeds.max() < 20.0
    for rel in list(rows)[:5]:
        a = np.fromfile(src / rel, "<f4").reshape(-1, 4)
        b = np.fromfile(out / rel, "<f4").reshape(-1, 4)
        labels = np.fromfile(
            src / rel.replace("velodyne", "sem_labels").replace(".bin", ".label"), np.uint8
        )
        still = (labels == 31) | (np.linalg.norm(a[:, :3], axis=1) < 1e-3)
        assert still.any() and (a.shape == b.shape)
        np.testing.assert_array_equal(a[still], b[still])  # ego body and empty rows stay
        assert (np.abs(b[~still, :3] - a[~still, :3]).max(axis=1) > 0).mean() > 0.9
