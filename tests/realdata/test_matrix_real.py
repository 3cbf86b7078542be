"""Every variant on every real frame: the (source x variant) matrix users build, with the
shipped default pipelines, on every real frame of ../shared/data.

Each cell builds one real tree (tests/real_trees.py) with `lads build`'s defaults, verifies
the output against its source (regenerating one item), and reads it back with the format's
own client: nuscenes-devkit's `NuScenes` and its lidarseg statistics, the SemanticKITTI label
map, plain numpy for the binary and CSV layouts.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest
import yaml

from lads.config import pipeline_for, variants_for
from lads.readers import get_reader
from lads.runner import run_build
from lads.sensors.profile import load_profile
from lads.verify import verify_tree
from tests.real_trees import NOT_BUILDABLE, REAL_SOURCES, real_scan_files
from tests.trees import SHARED_DATA

# Sensor-adaptation variants write the target sensor's intensity encoding, whatever the source.
TARGET_SENSOR = {"intensity-kitti": "hdl64e", "intensity-nuscenes": "hdl32e"}
# Sensor variants and motion-recorded need a sequence's poses, which some real trees lack:
# tests/realdata/test_sensor_real.py and test_motion_real.py build them on every real frame
# of their readers. The
# robustness suite's C- variants (one stage each, 24 per source) are built at their heaviest
# severity on every real tree by tests/realdata/test_augment_real.py.
CELLS = [
    (tree, variant)
    for tree, rs in REAL_SOURCES.items()
    for variant in variants_for(rs.reader)
    if not variant.startswith(("sensor-", "C-")) and variant != "motion-recorded"
]


def test_the_real_trees_hold_every_real_frame(shared_data):
    covered = {rel for rs in REAL_SOURCES.values() for rel in rs.covers()}
    missing = sorted(set(real_scan_files()) - covered - set(NOT_BUILDABLE))
    assert not missing, f"real frames no test tree holds: {missing}"
    assert len(covered) == 111


@pytest.fixture(scope="module")
def source_trees(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each real tree, built once per module on first use."""
    base = tmp_path_factory.mktemp("real_sources")

    class Trees(dict):
        def __missing__(self, name: str) -> Path:
            root = REAL_SOURCES[name].build(base / name)
            self[name] = root
            return root

    return Trees()


@pytest.mark.parametrize(("tree", "variant"), CELLS, ids=[f"{t}-{v}" for t, v in CELLS])
def test_default_pipeline_builds_verifies_and_reads_back(
    shared_data, source_trees, tmp_path, tree: str, variant: str
) -> None:
    rs = REAL_SOURCES[tree]
    src = source_trees[tree]
    pipeline = pipeline_for(rs.reader, variant)
    out = tmp_path / "out"
    report = run_build(
        rs.reader,
        src,
        out,
        pipeline,
        reader_options=rs.options,
        jobs=1,
        progress=False,
        figures=False,
    )
    assert report.complete, report.failed
    check = verify_tree(out, src, regenerate=1, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]
    reader = get_reader(rs.reader, src, **rs.options)
    assert report.items == len(reader.items()) > 0
    READ_BACK[rs.reader](out, src, rs.options, reader)
    encoding = load_profile(TARGET_SENSOR.get(variant, reader.sensor)).intensity
    built = get_reader(rs.reader, out, **rs.options)
    for item in built.items():
        intensity = built.read(item).points[:, 3]
        on_grid = np.abs(intensity / encoding.step - np.rint(intensity / encoding.step)) < 1e-3
        assert on_grid.all() and intensity.max(initial=0) <= np.float32(encoding.max_value)


def _kitti_layout(out: Path, src: Path, options: dict, reader) -> None:
    """Scans of 16-byte records, one uint32 label per point, semantic ids of the label map."""
    label_map = yaml.safe_load((SHARED_DATA / "semantickitti" / "semantic-kitti.yaml").read_text())
    allowed = set(label_map["labels"]) | {reader.particle_label}
    if reader.name == "wads":  # WADS adds falling (110) and accumulated (111) snow
        allowed |= {110, 111}
    for item in reader.items():
        scan = np.fromfile(out / item.relpath, dtype="<f4").reshape(-1, 4)
        assert np.isfinite(scan).all()
        labels = np.fromfile(out / item.label_relpath, dtype="<u4")
        assert labels.size == scan.shape[0]
        semantic = set(np.unique(labels & 0xFFFF).tolist())
        assert semantic <= allowed, sorted(semantic - allowed)
        assert all(s in label_map["learning_map"] for s in semantic - {110, 111})


def _nuscenes(out: Path, src: Path, options: dict, reader) -> None:
    """The devkit opens the output dataroot, loads every keyframe and counts its lidarseg."""
    from nuscenes.nuscenes import NuScenes
    from nuscenes.utils.data_classes import LidarPointCloud

    with contextlib.redirect_stdout(io.StringIO()) as said:
        nusc = NuScenes(version=options["version"], dataroot=str(out), verbose=False)
        nusc.list_lidarseg_categories(sort_by="count")
    assert "vehicle.ego" in said.getvalue() or "flat.driveable_surface" in said.getvalue()
    for sample in nusc.sample:
        sd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
        cloud = LidarPointCloud.from_file(str(out / sd["filename"]))
        raw = np.fromfile(out / sd["filename"], dtype="<f4").reshape(-1, 5)
        assert cloud.points.shape[1] == raw.shape[0] and np.isin(raw[:, 4], np.arange(32)).all()
        labels = np.fromfile(out / nusc.get("lidarseg", sd["token"])["filename"], dtype=np.uint8)
        assert labels.size == raw.shape[0] and labels.max(initial=0) < 32
        with contextlib.redirect_stdout(io.StringIO()):
            nusc.get_sample_lidarseg_stats(sample["token"], sort_by="count")


def _nuscenes_kitti(out: Path, src: Path, options: dict, reader) -> None:
    for item in reader.items():
        scan = np.fromfile(out / item.relpath, dtype="<f4").reshape(-1, 4)
        labels = np.fromfile(out / item.label_relpath, dtype=np.uint8)
        assert labels.size == scan.shape[0] and labels.max(initial=0) < 32
    assert (out / "train" / "0002" / "poses.txt").read_bytes() == (
        src / "train" / "0002" / "poses.txt"
    ).read_bytes()


def _radiate(out: Path, src: Path, options: dict, reader) -> None:
    for item in reader.items():
        rows = np.loadtxt(out / item.relpath, delimiter=",", ndmin=2)
        assert rows.shape[1] == 5 and np.isfinite(rows).all()
        assert np.isin(rows[:, 4], np.arange(32)).all()


def _nuscenes_scans(out: Path, src: Path, options: dict, reader) -> None:
    """The devkit's own parser reads every loose scan; labels keep one index per point."""
    from nuscenes.utils.data_classes import LidarPointCloud

    for item in reader.items():
        raw = np.fromfile(out / item.relpath, dtype="<f4").reshape(-1, 5)
        cloud = LidarPointCloud.from_file(str(out / item.relpath))
        assert cloud.points.shape[1] == raw.shape[0] and np.isin(raw[:, 4], np.arange(32)).all()
        if item.label_relpath is not None:
            labels = np.fromfile(out / item.label_relpath, dtype=np.uint8)
            assert labels.size == raw.shape[0] and labels.max(initial=0) < 32


READ_BACK = {
    "semantickitti": _kitti_layout,
    "wads": _kitti_layout,
    "nuscenes": _nuscenes,
    "nuscenes-kitti": _nuscenes_kitti,
    "nuscenes-scans": _nuscenes_scans,
    "radiate": _radiate,
}
