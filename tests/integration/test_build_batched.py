"""The batched build path (`--batch`, the default with --device cuda): the learned stage runs
several frames per forward pass, and nothing else changes.

Specification: the tree's bytes do not depend on the batch size or the job count; a frame
that breaks the batched stage fails alone and its batch-mates are built as usual.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from lads.config import find_pipeline, load_pipeline
from lads.runner import run_build
from lads.synth import write_synthetic_dataset

FRAMES = 5
SEQ = "sequences/00"


def _digest(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != "run_report.json"
    }


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("batched_src")
    write_synthetic_dataset(root, sensor="hdl64e", frames=FRAMES, layout="semantickitti", seed=7)
    return root


@pytest.fixture(scope="module")
def learned_snow():
    return load_pipeline(find_pipeline("semantickitti", "snow"))  # the shipped learned stage


@pytest.fixture(scope="module")
def one_by_one(source, learned_snow, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("one") / "out"
    report = run_build("semantickitti", source, out, learned_snow, seed=0, batch=1)
    assert report.complete and report.built == FRAMES
    return out


@pytest.mark.parametrize(("batch", "jobs"), [(3, 1), (FRAMES, 1), (2, 2)])
def test_bytes_do_not_depend_on_batch_size(source, learned_snow, one_by_one, tmp_path, batch, jobs):
    out = tmp_path / "batched"
    report = run_build("semantickitti", source, out, learned_snow, seed=0, batch=batch, jobs=jobs)
    assert report.complete
    assert _digest(out) == _digest(one_by_one)
    steps = report.step_ms_per_item()
    assert {"read", "stage:snow", "stage:intensity", "encode", "provenance"} <= set(steps)
    assert all(ms >= 0 for ms in steps.values())


def test_a_frame_that_breaks_the_batch_fails_alone(source, learned_snow, one_by_one, tmp_path):
    """A frame that is no scan of the sensor (tilted 40 degrees) makes the intensity stage
    refuse it; the batch is redone frame by frame, so only that frame fails."""
    bad_source = tmp_path / "src"
    shutil.copytree(source, bad_source)
    scan = bad_source / SEQ / "velodyne" / "000002.bin"
    pts = np.fromfile(scan, dtype=np.float32).reshape(-1, 4)
    a = np.deg2rad(40.0)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    pts[:, :3] = (pts[:, :3].astype(np.float64) @ rot.T).astype(np.float32)
    pts.tofile(scan)
    out = tmp_path / "out"
    report = run_build("semantickitti", bad_source, out, learned_snow, seed=0, batch=FRAMES)
    assert [item for item, _ in report.failed] == [f"semantickitti:{SEQ}/velodyne/000002.bin"]
    assert "is not a scan of that sensor" in report.failed[0][1]
    good, ref = _digest(out), _digest(one_by_one)
    for k in range(FRAMES):
        if k != 2:
            rel = f"{SEQ}/velodyne/{k:06d}.bin"
            assert good[rel] == ref[rel]
