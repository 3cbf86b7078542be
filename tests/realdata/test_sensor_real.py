"""`lads build --variant sensor-<profile>` on every real frame of the readers with poses.

SemanticKITTI: every labelled frame of sequence 00 (000000-000002, 000052, 000088, 000850,
004501) with KITTI's ground-truth poses standing in for SemanticKITTI's own poses.txt (the
reference data lack it: ../shared/data/SOURCES.md), in KITTI's record and (`--point-format
target`) in the HDL-32E's native one; sequence 90 has no poses, so its frames fail by name
and build with `neighbours: 0`. nuScenes: the 40 labelled keyframes of the
KITTI-style export with their lidar -> global poses, to the HDL-64E.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lads import provenance
from lads.config import pipeline_for
from lads.readers import get_reader
from lads.runner import run_build
from lads.sensors.profile import load_profile
from lads.verify import verify_tree
from tests.real_trees import KITTI_MORE, KITTI_SEQ00, KITTI_SEQ90, real_nuscenes_kitti
from tests.trees import SHARED_DATA, _link, _real_kitti_layout

KITTI_GT_POSES = SHARED_DATA / "kitti_odometry" / "poses" / "00.txt"


def _kitti_tree(root: Path) -> Path:
    """Every labelled real SemanticKITTI frame; sequence 00 with calib.txt and the stand-in
    poses, sequence 90 without poses."""
    seq00 = SHARED_DATA / "semantickitti" / "sequences" / "00"
    _real_kitti_layout(root, seq00, "00", list(KITTI_SEQ00), ("calib.txt", "times.txt"))
    more = SHARED_DATA / "semantickitti-more" / "sequences" / "00"
    _real_kitti_layout(root, more, "00", list(KITTI_MORE), ())
    _link(KITTI_GT_POSES, root / "sequences" / "00" / "poses.txt")
    seq90 = SHARED_DATA / "semantickitti-seqx" / "sequences" / "90"
    return _real_kitti_layout(root, seq90, "90", list(KITTI_SEQ90), ())


def _elevations_deg(xyz: np.ndarray) -> np.ndarray:
    xyz = xyz.astype(np.float64)
    return np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))


def _on_target_beams(xyz: np.ndarray, profile) -> float:
    """Median angular distance (deg) of the points from the target's nearest beam."""
    el = _elevations_deg(xyz)
    return float(np.median(np.abs(el[:, None] - np.asarray(profile.elevation_deg)).min(axis=1)))


def _build_and_verify(src, out, pipeline, *, figures):
    """Sequence 00 of `src` built with `pipeline` (two jobs) into `out`, verified against it
    with one frame regenerated."""
    report = run_build(
        "semantickitti",
        src,
        out,
        pipeline,
        reader_options={"sequences": ["00"]},
        jobs=2,
        progress=False,
        figures=figures,
    )
    assert report.complete, report.failed
    check = verify_tree(out, src, regenerate=1, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]


def test_real_kitti_frames_to_the_hdl32e(shared_data, tmp_path):
    src = _kitti_tree(tmp_path / "src")
    out = tmp_path / "seq00"
    _build_and_verify(src, out, pipeline_for("semantickitti", "sensor-hdl32e"), figures=True)
    target = load_profile("hdl32e")
    reader = get_reader("semantickitti", out, sequences=["00"], sensor="hdl32e")
    for item in reader.items():
        frame = reader.read(item)
        assert 10_000 < len(frame.points) < 70_000  # an HDL-32E scan, not the 120k of the 64E
        assert _on_target_beams(frame.xyz, target) < 0.05
        window, _ = provenance.read_source_scan(out, item.relpath)
        # 000000-000002 lend each other surfaces; the others are seconds apart: alone.
        assert len(window) == (
            3 if item.relpath.endswith(("00000.bin", "00001.bin", "00002.bin")) else 1
        )
    assert (out / "figures" / "preview.png").is_file()


def test_real_kitti_frames_in_the_hdl32es_native_record(shared_data, tmp_path):
    """`--point-format target`: each real frame at its KITTI path as nuScenes' 5 columns,
    the ring the channel of each point's beam; the tree verifies and lads reads it back."""
    src = _kitti_tree(tmp_path / "src")
    pipeline = pipeline_for("semantickitti", "sensor-hdl32e").with_overrides(point_format="target")
    out = tmp_path / "native"
    _build_and_verify(src, out, pipeline, figures=False)
    target = load_profile("hdl32e")
    reader = get_reader("semantickitti", out, sequences=["00"], sensor="hdl32e")
    assert len(reader.items()) == len(KITTI_SEQ00) + len(KITTI_MORE)
    for item in reader.items():
        frame = reader.read(item)
        assert frame.columns == ("x", "y", "z", "intensity", "ring")
        assert (out / item.relpath).stat().st_size == 20 * len(frame.points)
        assert 10_000 < len(frame.points) < 70_000
        ring = frame.points[:, 4]
        assert (target.channel_of(frame.xyz) == ring).all()
        assert _on_target_beams(frame.xyz, target) < 1e-3
        assert frame.labels is not None and len(frame.labels) == len(frame.points)


def test_a_sequence_without_poses_fails_by_name_and_builds_alone(shared_data, tmp_path):
    src = _kitti_tree(tmp_path / "src")
    pipeline = pipeline_for("semantickitti", "sensor-hdl32e")
    options = {"sequences": ["90"]}
    report = run_build(
        "semantickitti",
        src,
        tmp_path / "a",
        pipeline,
        reader_options=options,
        jobs=1,
        progress=False,
        figures=False,
    )
    # 000019 lies more than the window away from the others: it transfers alone, no poses
    # needed; the frames with neighbours fail, naming the file they need
    alone_frame = "sequences/90/velodyne/000019.bin"
    assert sorted(i for i, _ in report.failed) == sorted(
        f"semantickitti:sequences/90/velodyne/{k}.bin" for k in KITTI_SEQ90 if k != "000019"
    )
    assert all("poses.txt" in message for _, message in report.failed)
    assert report.built == 1
    out = tmp_path / "alone"
    report = run_build(
        "semantickitti",
        src,
        out,
        pipeline.with_overrides(neighbours=0),
        reader_options=options,
        jobs=1,
        progress=False,
        figures=False,
    )
    assert report.complete, report.failed
    assert (out / alone_frame).read_bytes() == (tmp_path / "a" / alone_frame).read_bytes()
    check = verify_tree(out, src, regenerate=1, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]


@pytest.mark.parametrize("target", ["hdl64e"])
def test_real_nuscenes_keyframes_to_a_64_beam_sensor(shared_data, tmp_path, target):
    src = real_nuscenes_kitti(tmp_path / "src")
    out = tmp_path / "out"
    pipeline = pipeline_for("nuscenes-kitti", f"sensor-{target}")
    report = run_build("nuscenes-kitti", src, out, pipeline, jobs=2, progress=False, figures=False)
    assert report.complete, report.failed
    check = verify_tree(out, src, regenerate=1, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]
    profile = load_profile(target)
    reader = get_reader("nuscenes-kitti", out, sensor="hdl64e")
    for item in reader.items():
        frame = reader.read(item)
        assert frame.labels is not None and frame.labels.max() < 31  # 31: ego body, dropped
        assert _on_target_beams(frame.xyz, profile) < 0.05
        step = profile.intensity.step
        assert np.allclose(frame.intensity / step, np.rint(frame.intensity / step), atol=1e-3)
