"""Readers on synthetic trees: listing, reading, byte-exact encoding and every error case.

Trees come from tests/trees.py (random points in each format, with duplicates and
near-origin points); no real data is read here.
"""

from __future__ import annotations

import io
import pickle
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lads.errors import (
    ConfigError,
    CorruptItemError,
    DatasetNotFoundError,
    InputDataError,
    InvalidPointsError,
    ReaderError,
)
from lads.frame import Item
from lads.physics.result import Outcome
from lads.readers import READERS, get_reader
from lads.readers.nuscenes import TABLES
from lads.sensors.profile import load_profile
from tests import trees

BUILDERS = {
    "semantickitti": trees.synthetic_semantickitti,
    "wads": trees.synthetic_wads,
    "voxelscape": trees.synthetic_voxelscape,
    "radiate": trees.synthetic_radiate,
    "nuscenes": trees.synthetic_nuscenes,
    "nuscenes-kitti": trees.synthetic_nuscenes_kitti,
    "nuscenes-scans": trees.synthetic_nuscenes_scans,
}
SCAN_GLOB = {
    "semantickitti": "sequences/*/velodyne/*.bin",
    "wads": "sequences/*/velodyne/*.bin",
    "voxelscape": "*/velodyne/*.bin",
    "radiate": "*/velo_lidar/*.csv",
    "nuscenes": "samples/LIDAR_TOP/*.pcd.bin",
    "nuscenes-kitti": "*/*/velodyne/*.bin",
    "nuscenes-scans": ("**/points.bin", "**/*.pcd.bin"),
}
BYTE_EXACT_ROLES = {"scan", "label", "orig_labels", "orig_sublabels"}


@pytest.fixture
def tree(synthetic_tree):
    """tree(name, **kwargs) -> (reader, root) for a fresh synthetic tree of that format."""

    def build(name: str, reader_options: dict | None = None, **kwargs):
        root = synthetic_tree(name, **kwargs)
        return get_reader(name, root, **(reader_options or {})), root

    return build


def _first(reader, predicate=lambda it: True) -> Item:
    return next(it for it in reader.items() if predicate(it))


# ----------------------------------------------------------------------------------------
# registry


def test_readers_dict_has_exactly_the_seven_formats():
    assert set(READERS) == {
        "semantickitti",
        "nuscenes",
        "nuscenes-kitti",
        "nuscenes-scans",
        "voxelscape",
        "wads",
        "radiate",
    }
    for name, cls in READERS.items():
        assert cls.name == name


def test_get_reader_unknown_name_lists_the_valid_ones(tmp_path):
    with pytest.raises(ConfigError) as err:
        get_reader("kitti360", tmp_path)
    for name in READERS:
        assert name in str(err.value)


def test_get_reader_unknown_option_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="sequences"):
        get_reader("semantickitti", tmp_path, sequence=["00"])


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_sensor_profile_exists_and_particle_label_is_an_int(name):
    cls = READERS[name]
    assert load_profile(cls.sensor).name == cls.sensor
    assert isinstance(cls.particle_label, int)


def test_voxelscape_profile_has_hdl64e_geometry_and_fine_unit_intensity():
    vox, kitti = load_profile("voxelscape64"), load_profile("hdl64e")
    assert vox.elevation_deg == kitti.elevation_deg
    assert vox.vertical_fov_deg == kitti.vertical_fov_deg
    enc = vox.intensity
    assert (enc.kind, enc.step, enc.max_value) == ("unit", 1e-4, 0.9999)
    assert enc.from_reflectivity(np.array([0.12345678, 3.0])).tolist() == pytest.approx(
        [0.1235, 0.9999], abs=1e-7
    )


# ----------------------------------------------------------------------------------------
# round trip and listing


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_encode_of_read_reproduces_every_source_file_byte_for_byte(tree, name):
    reader, root = tree(name)
    items = reader.items()
    assert items
    for item in items:
        frame = reader.read(item)
        encoded = reader.encode(frame)
        assert [e.relpath for e in encoded] == list(item.source_relpaths())
        for e in encoded:
            assert e.payload == (root / e.relpath).read_bytes(), e.relpath
            assert e.records == frame.points.shape[0]
            if e.record_bytes:
                assert len(e.payload) == e.records * e.record_bytes


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_items_are_sorted_complete_and_carry_the_dataset_name(tree, name):
    reader, root = tree(name)
    items = reader.items()
    relpaths = [it.relpath for it in items]
    assert relpaths == sorted(relpaths)
    globs = SCAN_GLOB[name] if isinstance(SCAN_GLOB[name], tuple) else (SCAN_GLOB[name],)
    on_disk = sorted(p.relative_to(root).as_posix() for g in globs for p in root.glob(g))
    assert relpaths == on_disk
    assert {it.dataset for it in items} == {name}
    assert len({it.item_id for it in items}) == len(items)


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_frames_keep_every_point_including_duplicates(tree, name):
    reader, root = tree(name)
    item = reader.items()[0]
    frame = reader.read(item)
    n_lines = (root / item.relpath).read_bytes().count(b"\n")
    n = (
        n_lines
        if name == "radiate"
        else (root / item.relpath).stat().st_size // (4 * len(reader.columns))
    )
    assert frame.points.shape == (n, len(reader.columns))
    assert frame.points.dtype == np.float32
    assert frame.columns == reader.columns
    assert frame.sensor == reader.sensor
    assert frame.n_source == n
    np.testing.assert_array_equal(frame.source_index, np.arange(n))
    assert (frame.outcome == Outcome.KEPT).all()
    assert np.unique(frame.points, axis=0).shape[0] < n  # the trees hold duplicate rows
    assert frame.points.flags.writeable


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_reader_survives_pickling(tree, name):
    reader, _ = tree(name)
    item = reader.items()[-1]
    clone = pickle.loads(pickle.dumps(reader))
    assert type(clone) is type(reader) and clone.root == reader.root
    assert clone.items() == reader.items()
    a, b = reader.read(item), clone.read(item)
    np.testing.assert_array_equal(a.points, b.points)


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_an_aligned_subset_encodes_to_consistent_files(tree, name):
    """What a stage returns (fewer points, labels selected alongside) encodes consistently."""
    reader, _ = tree(name)
    frame = reader.read(reader.items()[0])
    rows = np.arange(0, frame.points.shape[0], 2)
    lost = np.arange(1, frame.points.shape[0], 2)
    out = frame.select(
        rows,
        outcome=np.zeros(rows.size, np.uint8),
        lost_rows=lost,
        points=frame.points[rows].copy(),
    )
    for e in reader.encode(out):
        assert e.records == rows.size
        if e.record_bytes:
            assert len(e.payload) == rows.size * e.record_bytes
    again = reader.read(replace(frame.item))  # source untouched
    assert again.points.shape[0] == frame.points.shape[0]


# ----------------------------------------------------------------------------------------
# label dtypes


def test_label_dtypes_follow_each_format(tree):
    kitti, _ = tree("semantickitti")
    assert kitti.read(_first(kitti)).labels.dtype == np.uint32
    wads, _ = tree("wads")
    assert wads.read(_first(wads, lambda it: it.label_relpath)).labels.dtype == np.uint32
    vox, _ = tree("voxelscape")
    frame = vox.read(_first(vox))
    assert frame.labels.dtype == np.uint32
    assert frame.extra_labels["orig_labels"].dtype == np.int32
    assert frame.extra_labels["orig_sublabels"].dtype == np.int32
    assert (frame.extra_labels["orig_labels"] < 0).any()  # int32, not uint32
    nusc, _ = tree("nuscenes", panoptic=True)
    frame = nusc.read(_first(nusc))
    assert frame.labels.dtype == np.uint8
    assert frame.extra_labels["panoptic"].dtype == np.uint16
    rad, _ = tree("radiate")
    assert rad.read(_first(rad)).labels is None


def test_semantickitti_labels_split_into_semantic_and_instance(tree):
    reader, root = tree("semantickitti")
    item = _first(reader)
    labels = reader.read(item).labels
    raw = np.fromfile(root / item.label_relpath, dtype="<u4")
    np.testing.assert_array_equal(labels, raw)
    assert ((labels >> 16) > 0).any()
    np.testing.assert_array_equal((labels >> 16) << 16 | (labels & 0xFFFF), labels)


# ----------------------------------------------------------------------------------------
# nuScenes in the KITTI-style export


def test_nuscenes_kitti_items_labels_and_copied_poses(tree):
    reader, root = tree("nuscenes-kitti")
    items = reader.items()
    assert [it.relpath for it in items] == [
        "train/0001/velodyne/000000.bin",
        "train/0001/velodyne/000001.bin",
        "train/0002/velodyne/000000.bin",
        "val/0003/velodyne/000000.bin",
    ]
    assert items[0].label_relpath == "train/0001/sem_labels/000000.label"
    assert items[-1].label_relpath is None  # val/0003 has no sem_labels/
    frame = reader.read(items[0])
    assert frame.labels.dtype == np.uint8 and frame.columns == ("x", "y", "z", "intensity")
    assert (reader.sensor, reader.label_set, reader.particle_label) == ("hdl32e", "nuscenes", 0)
    assert reader.copied_files() == [
        f"{s}/poses.txt" for s in ("train/0001", "train/0002", "val/0003")
    ]


def test_nuscenes_kitti_sequences_are_scene_folders(tree):
    reader, root = tree("nuscenes-kitti", reader_options={"sequences": ["0002", "val/0003"]})
    assert {it.relpath.rsplit("/", 2)[0] for it in reader.items()} == {"train/0002", "val/0003"}
    assert get_reader("nuscenes-kitti", root, sequences="0001").copied_files() == [
        "train/0001/poses.txt"
    ]
    with pytest.raises(DatasetNotFoundError, match="'0009'.*Available"):
        get_reader("nuscenes-kitti", root, sequences=["0009"]).items()


# ----------------------------------------------------------------------------------------
# SemanticKITTI / WADS layout


def test_unlabelled_sequence_gives_items_without_labels(tree):
    reader, root = tree("semantickitti")
    items = reader.items()
    assert all(it.label_relpath is None for it in items if it.relpath.startswith("sequences/11/"))
    assert all(it.label_relpath for it in items if not it.relpath.startswith("sequences/11/"))
    item = _first(reader, lambda it: it.relpath.startswith("sequences/11/"))
    frame = reader.read(item)
    assert frame.labels is None
    assert [e.role for e in reader.encode(frame)] == ["scan"]


def test_sequences_option_restricts_items_and_copied_files(tree):
    reader, root = tree("semantickitti", reader_options={"sequences": ["01"]})
    assert {it.relpath.split("/")[1] for it in reader.items()} == {"01"}
    assert reader.copied_files() == [
        "sequences/01/calib.txt",
        "sequences/01/poses.txt",
        "sequences/01/times.txt",
    ]
    assert get_reader("semantickitti", root, sequences=[1, "11"]).sequences == ("01", "11")
    assert len(get_reader("semantickitti", root, sequences="11").items()) == 2
    with pytest.raises(DatasetNotFoundError, match="'07'"):
        get_reader("semantickitti", root, sequences=["07"]).items()
    (root / "sequences" / "01").rename(root / "sequences" / "1")  # a folder without padding
    picked = get_reader("semantickitti", root, sequences=["1"]).items()
    assert picked and {it.relpath.split("/")[1] for it in picked} == {"1"}


def test_copied_files_lists_calib_poses_times_present(tree):
    reader, root = tree("semantickitti", copied=("calib.txt", "times.txt"))
    assert reader.copied_files() == [
        f"sequences/{s}/{f}" for s in ("00", "01", "11") for f in ("calib.txt", "times.txt")
    ]
    assert all((root / rel).is_file() for rel in reader.copied_files())


def test_semantickitti_root_may_be_the_parent_of_dataset(tmp_path):
    trees.synthetic_semantickitti(tmp_path / "kitti" / "dataset")
    reader = get_reader("semantickitti", tmp_path / "kitti")
    assert reader.root == tmp_path / "kitti" / "dataset"
    assert reader.items()[0].relpath.startswith("sequences/")


def test_wads_reader_defaults(tree):
    reader, _ = tree("wads")
    assert (reader.name, reader.sensor, reader.particle_label) == ("wads", "wads64", 110)
    frame = reader.read(_first(reader))
    np.testing.assert_array_equal(frame.intensity, np.round(frame.intensity))


# ----------------------------------------------------------------------------------------
# new_item: the item a new scan would have (for writers of new trees, `lads synth`)


@pytest.mark.parametrize("name", ["semantickitti", "wads", "voxelscape"])
def test_new_item_is_what_items_lists_for_a_labelled_scan(tree, name):
    reader, _ = tree(name)
    labelled = [it for it in reader.items() if it.label_relpath is not None]
    assert labelled
    for item in labelled:
        sequence = item.relpath.split("/")[1 if name != "voxelscape" else 0]
        number = int(Path(item.relpath).stem[-6:])
        assert reader.new_item(sequence, number) == item


def test_new_item_zero_pads_the_scan_number(tmp_path):
    reader = get_reader("semantickitti", tmp_path)
    assert reader.new_item("08", 42) == Item(
        "semantickitti", "sequences/08/velodyne/000042.bin", "sequences/08/labels/000042.label"
    )
    item = get_reader("voxelscape", tmp_path).new_item("03", 7)
    assert item.source_relpaths() == (
        "03/velodyne/xyz_iom_000007.bin",
        "03/kitti_labels/xyz_iom_000007.label",
        "03/orig_labels/xyz_iom_000007.label",
        "03/orig_labels/xyz_iom_000007_subl.label",
    )


def test_semantickitti_sequence_file_names_the_copied_files(tree):
    reader, _ = tree("semantickitti")
    assert reader.copied_files() == sorted(
        reader.sequence_file(s, n) for s in ("00", "01", "11") for n in reader.copied_names
    )
    with pytest.raises(ConfigError, match="calib.txt, poses.txt, times.txt"):
        reader.sequence_file("00", "labels.txt")


def test_nuscenes_new_item_names_the_files_items_lists(tree):
    reader, _ = tree("nuscenes")
    log = "n015-2018-07-24-11-22-45+0800"  # tests/trees.py's log
    for item in reader.items():
        meta = dict(item.meta)
        filename = reader.keyframe_filename(log, int(meta["timestamp"]))
        new = reader.new_item(filename, meta["sample_data_token"], "v1.0-mini")
        assert new == replace(item, meta=new.meta)
        assert set(new.meta) <= set(item.meta)


# ----------------------------------------------------------------------------------------
# Voxelscape


def test_voxelscape_items_carry_both_orig_label_roles(tree):
    reader, _ = tree("voxelscape")
    item = reader.items()[0]
    assert item.relpath == "00/velodyne/xyz_iom_000000.bin"
    assert item.label_relpath == "00/kitti_labels/xyz_iom_000000.label"
    assert item.extra_relpaths == (
        ("orig_labels", "00/orig_labels/xyz_iom_000000.label"),
        ("orig_sublabels", "00/orig_labels/xyz_iom_000000_subl.label"),
    )
    assert reader.copied_files()[0] == "00/bboxs/xyz_iom_000000.pkl"


@pytest.mark.parametrize(
    ("options", "roles", "labelled"),
    [
        ({"orig_labels": False, "sublabels": False}, (), True),
        ({"sublabels": False}, ("orig_labels",), True),
        ({"kitti_labels": False, "orig_labels": False, "sublabels": False}, (), False),
    ],
)
def test_voxelscape_without_orig_labels(tree, options, roles, labelled):
    reader, root = tree("voxelscape", bboxs=False, **options)
    for item in reader.items():
        assert tuple(role for role, _ in item.extra_relpaths) == roles
        assert (item.label_relpath is not None) == labelled
        frame = reader.read(item)
        assert set(frame.extra_labels) == set(roles)
        for e in reader.encode(frame):
            assert e.payload == (root / e.relpath).read_bytes()
    assert reader.copied_files() == []


def test_voxelscape_sequences_option_and_dataset_parent(tmp_path):
    trees.synthetic_voxelscape(tmp_path / "VoxelScape" / "dataset", sequences={"00": 1, "05": 2})
    reader = get_reader("voxelscape", tmp_path / "VoxelScape", sequences=[5])
    assert reader.root == tmp_path / "VoxelScape" / "dataset"
    assert [it.relpath for it in reader.items()] == [
        "05/velodyne/xyz_iom_000000.bin",
        "05/velodyne/xyz_iom_000001.bin",
    ]


def test_voxelscape_orig_label_count_mismatch_names_the_file(tree):
    reader, root = tree("voxelscape")
    item = reader.items()[0]
    path = root / dict(item.extra_relpaths)["orig_labels"]
    path.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(CorruptItemError, match="xyz_iom_000000.label.*records but scan"):
        reader.read(item)


def test_voxelscape_missing_sublabel_file_names_it(tree):
    reader, root = tree("voxelscape")
    item = reader.items()[1]
    (root / dict(item.extra_relpaths)["orig_sublabels"]).unlink()
    with pytest.raises(CorruptItemError, match="xyz_iom_000001_subl.label: missing"):
        reader.read(item)


# ----------------------------------------------------------------------------------------
# RADIATE


def test_radiate_items_copied_files_and_sequence_root(tree):
    reader, root = tree("radiate")
    assert reader.copied_files() == [
        "fog_1/meta.json",
        "fog_1/velo_lidar.txt",
        "rain_2/meta.json",
        "rain_2/velo_lidar.txt",
    ]
    assert len(get_reader("radiate", root, sequences=["rain_2"]).items()) == 2
    single = get_reader("radiate", root / "fog_1")
    assert [it.relpath for it in single.items()][0] == "velo_lidar/000000.csv"
    assert single.copied_files() == ["meta.json", "velo_lidar.txt"]
    assert all(it.label_relpath is None for it in reader.items())


def test_radiate_number_format_is_five_significant_digits(tree):
    reader, root = tree("radiate")
    item = reader.items()[0]
    first = (root / item.relpath).read_text().splitlines()[:3]
    assert first[0].split(",")[1] == "0.00023476" and first[2].split(",")[1] == "12"
    frame = reader.read(item)
    moved = replace(frame, points=frame.points + np.float32(1 / 3))
    text = reader.encode(moved)[0].payload.decode()
    assert all(len(v.lstrip("-").replace(".", "").lstrip("0")) <= 5 for v in text.split(",")[:3])


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("1,2,3,4\n", "line 2 is '1,2,3,4'"),
        ("1,2,3,4,5,6\n", "line 2"),
        ("1,2,x,4,5\n", "line 2 is '1,2,x,4,5'; expected only numbers"),
        ("1,nan,3,4,5\n", "NaN or infinite"),
        ("\n", "line 2"),
    ],
)
def test_radiate_malformed_lines_name_file_and_line(tree, line, match):
    reader, root = tree("radiate")
    item = reader.items()[0]
    path = root / item.relpath
    lines = path.read_text().splitlines(keepends=True)
    path.write_text(lines[0] + line + "".join(lines[1:]))
    with pytest.raises(CorruptItemError, match=match) as err:
        reader.read(item)
    assert str(path) in str(err.value)


def test_radiate_blank_lines_at_the_end_are_no_points_and_a_header_is_named(tree):
    reader, root = tree("radiate")
    item = reader.items()[0]
    path = root / item.relpath
    n = len(reader.read(item).points)
    path.write_text(path.read_text() + "\n  \n\n")
    assert len(reader.read(item).points) == n
    path.write_text("x,y,z,intensity,ring\n" + path.read_text())
    with pytest.raises(CorruptItemError, match="line 1 is 'x,y,z,intensity,ring', a header"):
        reader.read(item)


# ----------------------------------------------------------------------------------------
# error cases shared by the binary formats

BINARY = ("semantickitti", "wads", "voxelscape", "nuscenes", "nuscenes-kitti")


@pytest.mark.parametrize("name", BINARY)
def test_truncated_scan_names_the_file_and_record_size(tree, name):
    reader, root = tree(name)
    item = reader.items()[0]
    path = root / item.relpath
    path.write_bytes(path.read_bytes()[:-3])
    record = 4 * len(reader.columns)
    with pytest.raises(CorruptItemError, match=f"{record}-byte records") as err:
        reader.read(item)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("name", BINARY)
def test_label_count_mismatch_names_the_label_file(tree, name):
    reader, root = tree(name)
    item = _first(reader, lambda it: it.label_relpath)
    label = root / item.label_relpath
    width = 1 if name.startswith("nuscenes") else 4
    label.write_bytes(label.read_bytes() + bytes(width))
    with pytest.raises(CorruptItemError, match="records but scan") as err:
        reader.read(item)
    assert str(label) in str(err.value)


@pytest.mark.parametrize("name", BINARY)
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_coordinates_are_rejected(tree, name, value):
    reader, root = tree(name)
    item = reader.items()[0]
    path = root / item.relpath
    pts = np.fromfile(path, dtype="<f4").reshape(-1, len(reader.columns))
    pts[5, 1] = value
    path.write_bytes(pts.tobytes())
    with pytest.raises(CorruptItemError, match="point 5, column 'y'") as err:
        reader.read(item)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("name", BINARY)
def test_missing_label_file_fails_at_read_time(tree, name):
    reader, root = tree(name)
    items = reader.items()
    item = _first(reader, lambda it: it.label_relpath)
    (root / item.label_relpath).unlink()
    if name != "nuscenes":  # the devkit refuses a database with a missing label file
        assert reader.items() == items  # still listed: the labels folder says it must exist
    with pytest.raises(CorruptItemError, match="missing") as err:
        reader.read(item)
    assert str(root / item.label_relpath) in str(err.value)


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_unreadable_scan_names_the_file(tree, name):
    reader, root = tree(name)
    item = reader.items()[0]
    path = root / item.relpath
    path.unlink()
    path.mkdir()  # a directory where the scan should be: unreadable even as root
    with pytest.raises(CorruptItemError, match="cannot read") as err:
        reader.read(item)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("name", sorted(READERS))
def test_missing_and_empty_roots_are_dataset_not_found(tmp_path, name):
    with pytest.raises(DatasetNotFoundError, match="no such folder|no v1.0"):
        get_reader(name, tmp_path / "absent").items()
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetNotFoundError, match="expected"):
        get_reader(name, tmp_path / "empty").items()


@pytest.mark.parametrize("name", ("semantickitti", "voxelscape", "radiate", "nuscenes-kitti"))
def test_layout_without_scans_is_dataset_not_found(tmp_path, name):
    folder = {
        "semantickitti": "sequences/00/velodyne",
        "voxelscape": "00/velodyne",
        "radiate": "fog/velo_lidar",
        "nuscenes-kitti": "train/0001/velodyne",
    }[name]
    (tmp_path / folder).mkdir(parents=True)
    with pytest.raises(DatasetNotFoundError, match="no scans found"):
        get_reader(name, tmp_path).items()


# ----------------------------------------------------------------------------------------
# encode-side checks


def test_encode_rejects_frames_that_do_not_fit_the_files(tree):
    reader, _ = tree("semantickitti")
    frame = reader.read(_first(reader))
    with pytest.raises(InputDataError, match="one uint32 per point"):
        reader.encode(replace(frame, labels=frame.labels[:-1]))
    with pytest.raises(InputDataError, match="no 'label' array"):
        reader.encode(replace(frame, labels=None))
    with pytest.raises(InputDataError, match="do not fit uint32"):
        reader.encode(replace(frame, labels=frame.labels.astype(np.int64) - 2**33))
    bad = frame.points.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InvalidPointsError, match="NaN"):
        reader.encode(replace(frame, points=bad))
    with pytest.raises(InvalidPointsError, match=r"expected \(M, 4\)"):
        reader.encode(replace(frame, points=frame.points[:, :3]))
    ok = reader.encode(replace(frame, labels=frame.labels.astype(np.int64)))
    assert ok[1].payload == reader.encode(frame)[1].payload


def test_encode_checks_extra_roles(tree):
    reader, _ = tree("voxelscape")
    frame = reader.read(_first(reader))
    with pytest.raises(InputDataError, match="orig_sublabels"):
        reader.encode(
            replace(frame, extra_labels={"orig_labels": frame.extra_labels["orig_labels"]})
        )
    nusc, _ = tree("nuscenes")
    frame = nusc.read(_first(nusc))
    with pytest.raises(InputDataError, match="do not fit uint8"):
        nusc.encode(replace(frame, labels=frame.labels.astype(np.int32) + 255))


def test_radiate_encode_rejects_wrong_columns(tree):
    reader, _ = tree("radiate")
    frame = reader.read(_first(reader))
    with pytest.raises(InvalidPointsError, match=r"expected \(M, 5\)"):
        reader.encode(replace(frame, points=frame.points[:, :4]))


# ----------------------------------------------------------------------------------------
# nuScenes


def test_nuscenes_items_are_labelled_keyframes_with_tokens(tree):
    reader, root = tree("nuscenes")
    items = reader.items()
    assert len(items) == 3
    for item in items:
        assert item.relpath.startswith("samples/LIDAR_TOP/")
        token = dict(item.meta)["sample_data_token"]
        assert item.label_relpath == f"lidarseg/v1.0-mini/{token}_lidarseg.bin"
    frame = reader.read(items[0])
    raw = np.fromfile(root / items[0].relpath, dtype="<f4").reshape(-1, 5)
    np.testing.assert_array_equal(frame.points[:, 4], raw[:, 4])  # ring kept
    assert frame.columns[4] == "ring"


def test_nuscenes_include_sweeps_adds_unlabelled_sweeps(tree):
    reader, root = tree("nuscenes", reader_options={"include_sweeps": True})
    items = reader.items()
    sweeps = [it for it in items if it.relpath.startswith("sweeps/")]
    assert len(items) == 5 and len(sweeps) == 2
    assert all(it.label_relpath is None and it.extra_relpaths == () for it in sweeps)
    # A record whose file is gone stays an item (never a silent gap) and fails when read.
    (root / sweeps[0].relpath).unlink()
    assert reader.items() == items
    with pytest.raises(CorruptItemError, match="No such file"):
        reader.read(sweeps[0])


def test_nuscenes_copied_files_are_tables_and_maps(tree):
    reader, root = tree("nuscenes", panoptic=True)
    copied = reader.copied_files()
    assert {f"v1.0-mini/{t}.json" for t in TABLES} <= set(copied)
    assert {"v1.0-mini/lidarseg.json", "v1.0-mini/panoptic.json"} <= set(copied)
    assert [c for c in copied if c.startswith("maps/")]
    assert not [c for c in copied if c.startswith(("lidarseg/", "panoptic/", "samples/"))]


def test_nuscenes_version_autodetect_and_errors(tree):
    reader, root = tree("nuscenes")
    assert reader.resolved_version() == "v1.0-mini"
    shutil.copytree(root / "v1.0-mini", root / "v1.0-trainval")
    with pytest.raises(ConfigError, match="v1.0-mini.*v1.0-trainval"):
        get_reader("nuscenes", root).items()
    assert len(get_reader("nuscenes", root, version="v1.0-mini").items()) == 3
    with pytest.raises(DatasetNotFoundError, match="v1.0-test"):
        get_reader("nuscenes", root, version="v1.0-test").items()


@pytest.mark.parametrize("table", ["sample_data", "map", "category"])
def test_nuscenes_missing_table_is_named(tree, table):
    reader, root = tree("nuscenes")
    (root / "v1.0-mini" / f"{table}.json").unlink()
    with pytest.raises(DatasetNotFoundError, match=f"{table}.json"):
        reader.items()


def test_nuscenes_extra_label_file_makes_the_database_unloadable(tree):
    reader, root = tree("nuscenes")
    (root / "lidarseg" / "v1.0-mini" / "stray_lidarseg.bin").write_bytes(b"\x00")
    with pytest.raises(ReaderError, match="4 label files but 3 lidarseg records"):
        reader.items()


def test_nuscenes_without_lidarseg_table_lists_unlabelled_keyframes(tree):
    reader, root = tree("nuscenes")
    (root / "v1.0-mini" / "lidarseg.json").unlink()
    items = reader.items()
    assert len(items) == 3 and all(it.label_relpath is None for it in items)


def test_nuscenes_panoptic_round_trips_as_arrays(tree):
    reader, root = tree("nuscenes", panoptic=True)
    for item in reader.items():
        roles = dict(item.extra_relpaths)
        assert roles["panoptic"].startswith("panoptic/v1.0-mini/")
        frame = reader.read(item)
        encoded = {e.role: e for e in reader.encode(frame)}
        for role in ("scan", "label"):
            assert encoded[role].payload == (root / encoded[role].relpath).read_bytes()
        with np.load(io.BytesIO(encoded["panoptic"].payload)) as npz:
            written = npz["data"]
        original = np.load(root / roles["panoptic"])["data"]
        assert written.dtype == original.dtype == np.uint16
        np.testing.assert_array_equal(written, original)
        np.testing.assert_array_equal(written // 1000, frame.labels)
        assert encoded["panoptic"].payload == reader.encode(frame)[2].payload  # deterministic


def test_nuscenes_corrupt_panoptic_names_the_file(tree):
    reader, root = tree("nuscenes", panoptic=True)
    item = reader.items()[0]
    path = root / dict(item.extra_relpaths)["panoptic"]
    path.write_bytes(b"not a zip")
    with pytest.raises(CorruptItemError, match="cannot read nuScenes panoptic") as err:
        reader.read(item)
    assert str(path) in str(err.value)
    np.savez_compressed(path, data=np.zeros(3, np.uint16))
    with pytest.raises(CorruptItemError, match="has .* points"):
        reader.read(item)


def test_nuscenes_output_tree_loads_with_the_devkit(tree, tmp_path):
    from nuscenes.nuscenes import NuScenes
    from nuscenes.utils.data_classes import LidarPointCloud
    from nuscenes.utils.data_io import load_bin_file

    reader, root = tree("nuscenes", panoptic=True)
    out = tmp_path / "out"
    trees.write_like_the_runner(reader, out)
    source = NuScenes("v1.0-mini", dataroot=str(root), verbose=False)
    nusc = NuScenes("v1.0-mini", dataroot=str(out), verbose=False)
    assert len(nusc.lidarseg) == len(source.lidarseg) == 3
    assert len(nusc.panoptic) == 3
    for rec in nusc.lidarseg:
        sd = nusc.get("sample_data", rec["sample_data_token"])
        pc = LidarPointCloud.from_file(str(out / sd["filename"]))
        labels = load_bin_file(str(out / rec["filename"]), "lidarseg")
        assert pc.points.shape == (4, labels.size)
    for rec in nusc.panoptic:
        got = load_bin_file(str(out / rec["filename"]), "panoptic")
        np.testing.assert_array_equal(got, load_bin_file(str(root / rec["filename"]), "panoptic"))


# ----------------------------------------------------------------------------------------
# names that cannot be read are items that fail, never silent gaps


def _break(path, how: str) -> str:
    """Replace the scan file at `path` by a broken entry; returns the expected reason."""
    path.unlink()
    if how == "directory":
        path.mkdir()
        return "a directory"
    if how == "dangling":
        path.symlink_to(path.with_name("gone.bin"))
        return "dangling symbolic link"
    if how == "self_loop":
        path.symlink_to(path.name)
        return "symbolic link loop"
    other = path.with_name("other" + path.suffix)  # a two-link loop
    other.symlink_to(path.name)
    path.symlink_to(other.name)
    return "symbolic link loop"


FILE_READERS = ("semantickitti", "wads", "voxelscape", "radiate", "nuscenes-kitti")


@pytest.mark.parametrize("name", FILE_READERS)
@pytest.mark.parametrize("how", ["directory", "dangling", "self_loop", "two_link_loop"])
def test_an_unreadable_scan_name_is_listed_and_fails_with_its_reason(tree, name, how):
    reader, root = tree(name)
    before = reader.items()
    item = before[0]
    reason = _break(root / item.relpath, how)
    after = reader.items()
    extra = 1 if how == "two_link_loop" else 0  # the loop's second name is a scan name too
    assert len(after) == len(before) + extra and item in after
    with pytest.raises(CorruptItemError, match=reason) as err:
        reader.read(item)
    assert str(root / item.relpath) in str(err.value)


@pytest.mark.parametrize("name", FILE_READERS + ("nuscenes",))
def test_an_empty_scan_is_a_corrupt_item(tree, name):
    reader, root = tree(name)
    item = reader.items()[0]
    (root / item.relpath).write_bytes(b"")
    with pytest.raises(CorruptItemError, match="holds no point"):
        reader.read(item)


@pytest.mark.parametrize("name", BINARY)
def test_absurd_coordinates_are_a_corrupt_item(tree, name):
    reader, root = tree(name)
    item = reader.items()[0]
    path = root / item.relpath
    pts = np.fromfile(path, dtype="<f4").reshape(-1, len(reader.columns))
    pts[3, 2] = 1e30
    path.write_bytes(pts.tobytes())
    with pytest.raises(CorruptItemError, match="point 3, column 'z' = 1e.30 m"):
        reader.read(item)


def test_voxelscape_devkit_loader_labels_are_carried_not_dropped(tree):
    # The devkit loaders' tree: sequences/SS/velodyne + sequences/SS/labels (int32).
    reader, root = tree("voxelscape", kitti_labels=False, orig_labels=False, sublabels=False)
    for scan in sorted(root.glob("*/velodyne/*.bin")):
        n = scan.stat().st_size // 16
        labels = np.arange(n, dtype="<i4") - 1
        (scan.parent.parent / "labels").mkdir(exist_ok=True)
        (scan.parent.parent / "labels" / f"{scan.stem}.label").write_bytes(labels.tobytes())
    item = reader.items()[0]
    assert dict(item.extra_relpaths)["devkit_labels"].endswith(
        f"labels/{Path(item.relpath).stem}.label"
    )
    frame = reader.read(item)
    assert frame.extra_labels["devkit_labels"].dtype == np.int32
    encoded = {e.role: e for e in reader.encode(frame)}
    assert (
        encoded["devkit_labels"].payload
        == (root / dict(item.extra_relpaths)["devkit_labels"]).read_bytes()
    )


def test_read_scan_reads_a_scan_file_through_its_reader_and_refuses_a_stranger(
    synthetic_tree, tmp_path
):
    from lads.errors import InputDataError
    from lads.readers import get_reader, read_scan

    root = synthetic_tree("semantickitti")
    reader = get_reader("semantickitti", root)
    item = reader.items()[0]
    frame = read_scan("semantickitti", root, root / item.relpath)
    np.testing.assert_array_equal(frame.points, reader.read(item).points)
    assert frame.labels is not None
    stranger = tmp_path / "000000.bin"
    stranger.write_bytes((root / item.relpath).read_bytes())
    with pytest.raises(InputDataError, match="not a scan of the semantickitti tree"):
        read_scan("semantickitti", root, stranger)


def test_a_four_column_file_in_a_five_column_layout_is_refused_by_its_ring(tmp_path):
    """20 x N bytes also divide a 4-column file of 5k points: its values land in the ring
    column as intensities and coordinates, which are no laser numbers."""
    from lads.errors import CorruptItemError

    rng = np.random.default_rng(0)
    xyz = rng.uniform(-30.0, 30.0, (5000, 3))
    four = np.column_stack([xyz, rng.integers(0, 255, 5000)]).astype("<f4")
    four.tofile(tmp_path / "scan.pcd.bin")
    reader = get_reader("nuscenes-scans", tmp_path)
    with pytest.raises(CorruptItemError, match="'ring' column are not laser numbers"):
        reader.read(reader.items()[0])
    five = np.column_stack([four, np.arange(5000) % 32]).astype("<f4")
    five.tofile(tmp_path / "scan.pcd.bin")
    assert reader.read(reader.items()[0]).points.shape == (5000, 5)
