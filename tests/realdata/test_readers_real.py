"""Readers on the real sample files of ../shared/data (symlinked into tmp trees).

SemanticKITTI and WADS (3 frames each), RADIATE (3 CSV frames) and a minimal v1.0-mini
nuScenes database built around two real keyframes and one real sweep (tests/trees.py).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from lads.errors import ReaderError
from lads.readers import get_reader
from tests import trees

pytestmark = pytest.mark.realdata

# sha256 of the real files (../shared/data/SOURCES.md): the round trip must give them back.
SHA256 = {
    "sequences/00/velodyne/000000.bin": (
        "bf272996d5b6d25cc5589e1089137cb20a98b63bd4823a7fea5631b359f6d68c"
    ),
    "sequences/00/labels/000000.label": (
        "7fef55d3447e5af16eec9001af713b1aeb5b73d16fc756a5f9fe13ebff83c2ca"
    ),
    "sequences/36/velodyne/042223.bin": (
        "7a6c6313a5c0364de69740818301886c7c8f3600f3787a2ab5f345e7b8bc9d25"
    ),
    "sequences/36/labels/042223.label": (
        "476257f8f11a02a6989e5fabe3e488d1a769b95c517c748aeaf8bc870fe911aa"
    ),
    "tiny_foggy/velo_lidar/000018.csv": (
        "0d6ffae32aad3c441e5df41e2b08e98b1a38d5a26b9e08abe5585b106403b98d"
    ),
    trees.NUSC_FULL_SAMPLE: "5f8f9b1b199ceff7d41cd319021a7a7b02dcd44d41f622a9e65a6a4a6be3cbdb",
}


def _assert_round_trip(reader, root: Path) -> dict[str, bytes]:
    """encode(read(item)) == every source file of every item; returns payloads by relpath."""
    payloads = {}
    for item in reader.items():
        encoded = reader.encode(reader.read(item))
        assert [e.relpath for e in encoded] == list(item.source_relpaths())
        for e in encoded:
            assert e.payload == (root / e.relpath).read_bytes(), e.relpath
            payloads[e.relpath] = e.payload
    for rel, digest in SHA256.items():
        if rel in payloads:
            assert hashlib.sha256(payloads[rel]).hexdigest() == digest
    return payloads


def test_semantickitti_real_frames_round_trip(real_tree):
    root = real_tree("semantickitti")
    reader = get_reader("semantickitti", root)
    items = reader.items()
    assert [it.relpath for it in items] == [f"sequences/00/velodyne/00000{i}.bin" for i in range(3)]
    assert reader.copied_files() == ["sequences/00/calib.txt", "sequences/00/times.txt"]
    frame = reader.read(items[0])
    assert frame.points.shape == (124_668, 4) and frame.labels.shape == (124_668,)
    assert frame.labels.dtype == np.uint32
    assert set(np.unique(frame.labels >> 16)) >= set(range(208, 220))
    assert frame.intensity.max() <= np.float32(0.99)
    payloads = _assert_round_trip(reader, root)
    assert "sequences/00/velodyne/000000.bin" in payloads


def test_wads_real_frames_round_trip_with_duplicates(real_tree):
    root = real_tree("wads")
    reader = get_reader("wads", root)
    items = reader.items()
    assert len(items) == 3
    frame = reader.read(items[0])
    n = frame.points.shape[0]
    assert n == 209_297
    duplicates = n - np.unique(frame.points, axis=0).shape[0]
    assert duplicates / n > 0.40  # kept, not de-duplicated
    assert 110 in set(np.unique(frame.labels & 0xFFFF))
    np.testing.assert_array_equal(frame.intensity, np.round(frame.intensity))
    _assert_round_trip(reader, root)


def test_radiate_real_frames_read_and_round_trip(shared_data, tmp_path):
    root = trees.real_radiate(tmp_path / "radiate")
    reader = get_reader("radiate", root)
    items = reader.items()
    assert [it.relpath for it in items] == [
        f"tiny_foggy/velo_lidar/0000{i}.csv" for i in (18, 19, 20)
    ]
    assert reader.copied_files() == ["tiny_foggy/meta.json", "tiny_foggy/velo_lidar.txt"]
    for item, n in zip(items, (20_265, 20_448, 20_714), strict=True):
        frame = reader.read(item)
        assert frame.points.shape == (n, 5)
        assert (root / item.relpath).read_bytes().count(b"\n") == n
        ring = frame.points[:, 4]
        np.testing.assert_array_equal(ring, np.round(ring))
        assert ring.min() >= 0 and ring.max() <= 31
        assert frame.labels is None
    _assert_round_trip(reader, root)


@pytest.fixture
def nusc_root(shared_data, tmp_path) -> Path:
    return trees.real_nuscenes(tmp_path / "nuscenes")


def test_nuscenes_items_are_the_two_keyframes(nusc_root):
    reader = get_reader("nuscenes", nusc_root)
    items = reader.items()
    assert [it.relpath for it in items] == [trees.NUSC_FULL_SAMPLE, trees.NUSC_TINY_SAMPLE]
    tiny = items[1]
    assert dict(tiny.meta)["sample_data_token"] == trees.NUSC_TINY_TOKEN
    assert tiny.label_relpath == f"lidarseg/v1.0-mini/{trees.NUSC_TINY_TOKEN}_lidarseg.bin"


def test_nuscenes_real_keyframes_keep_the_ring_column_and_round_trip(nusc_root):
    reader = get_reader("nuscenes", nusc_root)
    full, tiny = reader.items()
    frame = reader.read(full)
    assert frame.points.shape == (34_688, 5)
    assert frame.columns == ("x", "y", "z", "intensity", "ring")
    ring = frame.points[:, 4].astype(int)
    assert np.bincount(ring).tolist() == [1084] * 32  # 32 rings x 1,084, firing order
    np.testing.assert_array_equal(ring[:32], np.arange(32))
    small = reader.read(tiny)
    assert small.points.shape == (40, 5) and small.labels.dtype == np.uint8
    near = np.linalg.norm(small.xyz, axis=1) < 1.1
    assert near.any() and (small.labels[near] == 31).all()  # vehicle.ego kept
    _assert_round_trip(reader, nusc_root)


def test_nuscenes_runner_like_output_loads_with_the_devkit(nusc_root, tmp_path):
    from nuscenes.nuscenes import NuScenes
    from nuscenes.utils.data_classes import LidarPointCloud
    from nuscenes.utils.data_io import load_bin_file

    reader = get_reader("nuscenes", nusc_root)
    out = tmp_path / "out"
    trees.write_like_the_runner(reader, out)
    source = NuScenes("v1.0-mini", dataroot=str(nusc_root), verbose=False)
    nusc = NuScenes("v1.0-mini", dataroot=str(out), verbose=False)
    assert len(nusc.lidarseg) == len(source.lidarseg) == 2
    for rec in nusc.lidarseg:
        sd = nusc.get("sample_data", rec["sample_data_token"])
        pc = LidarPointCloud.from_file(str(out / sd["filename"]))
        labels = load_bin_file(str(out / rec["filename"]), "lidarseg")
        assert pc.points.shape[1] == labels.size
    full = nusc.get("sample_data", trees.token(trees.NUSC_FULL_SAMPLE))
    assert LidarPointCloud.from_file(str(out / full["filename"])).points.shape == (4, 34_688)

    # The trap of docs/formats.md §2.5: one extra file in lidarseg/<version>/ breaks loading.
    (out / "lidarseg" / "v1.0-mini" / "extra_lidarseg.bin").write_bytes(b"\x00")
    with pytest.raises(AssertionError, match="3 label files but 2 lidarseg records"):
        NuScenes("v1.0-mini", dataroot=str(out), verbose=False)
    with pytest.raises(ReaderError, match="3 label files but 2 lidarseg records"):
        get_reader("nuscenes", out).items()


def test_nuscenes_include_sweeps_adds_the_real_sweep(nusc_root):
    reader = get_reader("nuscenes", nusc_root, include_sweeps=True)
    items = reader.items()
    assert len(items) == 3
    sweep = items[2]
    assert sweep.relpath == trees.NUSC_TINY_SWEEP and sweep.label_relpath is None
    frame = reader.read(sweep)
    assert frame.points.shape == (100, 5) and frame.labels is None
    _assert_round_trip(reader, nusc_root)


def test_the_real_poses_and_calibration_are_rigid_transforms(shared_data):
    """Every real pose file and calib.txt passes the rigidity check, with a margin of four
    orders of magnitude: the check only refuses broken files."""
    from lads.readers.poses import RIGID_TOLERANCE, kitti_velodyne_to_camera, read_pose_lines

    files = sorted(shared_data.rglob("poses.txt")) + [shared_data / "kitti_odometry/poses/00.txt"]
    assert len(files) >= 2
    for path in files:
        rot = read_pose_lines(path, "poses")[:, :3, :3]
        off = np.abs(np.einsum("kji,kjl->kil", rot, rot) - np.eye(3)).max()
        assert off < 1e-4 * RIGID_TOLERANCE, (path, off)
    for path in sorted(shared_data.rglob("calib.txt")):
        kitti_velodyne_to_camera(path)
