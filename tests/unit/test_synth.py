"""lads.synth writes complete, KITTI-like SemanticKITTI, nuScenes and Voxelscape trees from
nothing."""

import json
import re
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from lads.errors import ConfigError, SensorProfileError
from lads.physics.materials import class_materials
from lads.readers import get_reader
from lads.readers.nuscenes import TABLES, NuScenesReader
from lads.readers.semantickitti import SemanticKittiReader
from lads.readers.voxelscape import VoxelscapeReader
from lads.release import RELEASE_VARIANTS, synthetic_table
from lads.sensors.measure import rings_from_scan_order
from lads.sensors.profile import load_profile
from lads.synth import SynthSummary, synth_frames, write_synthetic_dataset
from lads.synth.command import synth_command
from lads.synth.nuscenes import SENSOR_TRANSLATION, lidarseg_classes, quaternion_wxyz
from lads.synth.parts import Part
from lads.synth.voxelscape import voxelscape_ids
from lads.synth.writer import NUSC_KEYFRAME_US, NUSC_LOG, NUSC_T0_US

# SemanticKITTI raw ids the street promises within 5 frames.
PROMISED = {
    "road": 40, "lane-marking": 60, "sidewalk": 48, "building": 50, "car": 10, "moving-car": 252,
    "person": 30, "moving-person": 254, "pole": 80, "traffic-sign": 81, "trunk": 71,
    "vegetation": 70, "terrain": 72,
}  # fmt: skip
THINGS = {10, 252, 30, 254}


@pytest.fixture(scope="module")
def frames5():
    return list(synth_frames("hdl64e", frames=5, seed=0))


@pytest.fixture(scope="module")
def kitti_tree(tmp_path_factory):
    root = tmp_path_factory.mktemp("skitti")
    return root, write_synthetic_dataset(root, frames=3, seed=0, sequence="04")


@pytest.fixture(scope="module")
def voxel_tree(tmp_path_factory):
    root = tmp_path_factory.mktemp("voxelscape")
    return root, write_synthetic_dataset(root, frames=2, seed=0, layout="voxelscape")


@pytest.fixture(scope="module")
def nusc_tree(tmp_path_factory):
    root = tmp_path_factory.mktemp("nuscenes")
    return root, write_synthetic_dataset(root, sensor="hdl32e", frames=3, layout="nuscenes")


@pytest.fixture(scope="module")
def frames32():
    return list(synth_frames("hdl32e", frames=3, seed=0))


def _world(frame):
    return frame.xyz.astype(np.float64) @ frame.pose[:3, :3].T + frame.pose[:3, 3]


def _tree_files(root):
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


def test_semantickitti_tree_has_every_file_with_consistent_sizes(kitti_tree):
    root, summary = kitti_tree
    seq = "sequences/04"
    names = [f"{k:06d}" for k in range(3)]
    expected = [f"{seq}/{f}" for f in ("calib.txt", "poses.txt", "times.txt")]
    expected += [f"{seq}/velodyne/{n}.bin" for n in names]
    expected += [f"{seq}/labels/{n}.label" for n in names]
    assert isinstance(summary, SynthSummary)
    assert summary.files == tuple(sorted(expected)) == tuple(_tree_files(root))
    assert (summary.layout, summary.sensor, summary.frames) == ("semantickitti", "hdl64e", 3)
    for name, n in zip(names, summary.points_per_frame, strict=True):
        assert (root / seq / "velodyne" / f"{name}.bin").stat().st_size == 16 * n
        assert (root / seq / "labels" / f"{name}.label").stat().st_size == 4 * n
        assert n > 60_000


def test_semantickitti_calib_poses_and_times_are_kitti_text(kitti_tree):
    root, _ = kitti_tree
    seq = root / "sequences/04"
    calib = seq.joinpath("calib.txt").read_text().splitlines()
    assert [line.split(":")[0] for line in calib] == ["P0", "P1", "P2", "P3", "Tr"]
    assert all(len(line.split()[1:]) == 12 for line in calib)
    tr = np.eye(4)
    tr[:3] = np.array(calib[4].split()[1:], dtype=float).reshape(3, 4)
    assert np.allclose(tr[:3, :3] @ tr[:3, :3].T, np.eye(3), atol=1e-6)  # a rigid transform
    assert np.allclose(tr[:3, :3] @ [1, 0, 0], [0, 0, 1], atol=0.02)  # velodyne x = cam z
    poses = np.loadtxt(seq / "poses.txt").reshape(-1, 3, 4)
    assert poses.shape == (3, 3, 4)
    assert np.array_equal(poses[0], np.eye(4)[:3])
    forward = np.diff(poses[:, 2, 3])  # cam0 z looks forward
    assert np.allclose(forward, 1.0, atol=0.02)
    times = seq.joinpath("times.txt").read_text().splitlines()
    assert times == ["0.000000e+00", "1.000000e-01", "2.000000e-01"]


def test_voxelscape_tree_layout_and_label_files(voxel_tree):
    root, summary = voxel_tree
    names = [f"xyz_iom_{k:06d}" for k in range(2)]
    expected = [f"00/velodyne/{n}.bin" for n in names]
    expected += [f"00/kitti_labels/{n}.label" for n in names]
    expected += [f"00/orig_labels/{n}.label" for n in names]
    expected += [f"00/orig_labels/{n}_subl.label" for n in names]
    assert summary.files == tuple(sorted(expected)) == tuple(_tree_files(root))
    for name, n in zip(names, summary.points_per_frame, strict=True):
        assert (root / "00/velodyne" / f"{name}.bin").stat().st_size == 16 * n
        for label in (f"kitti_labels/{name}", f"orig_labels/{name}", f"orig_labels/{name}_subl"):
            assert (root / "00" / f"{label}.label").stat().st_size == 4 * n


def test_voxelscape_ids_use_voxelscape_meanings_not_semantickitti(voxel_tree):
    root, _ = voxel_tree
    frame = next(synth_frames("hdl64e", frames=1, seed=0))
    kitti = np.fromfile(root / "00/kitti_labels/xyz_iom_000000.label", dtype="<u4")
    orig = np.fromfile(root / "00/orig_labels/xyz_iom_000000.label", dtype="<i4")
    subl = np.fromfile(root / "00/orig_labels/xyz_iom_000000_subl.label", dtype="<i4")
    sem = kitti & 0xFFFF
    assert set(np.unique(sem)) <= set(class_materials("voxelscape"))
    assert np.array_equal(kitti >> 16, frame.labels >> 16)  # same instances
    assert np.array_equal(orig, subl // 10)
    expected = {  # part: (kitti_labels id, orig class, sub-label)
        Part.MOVING_CAR: (10, 11, 111),  # 252 would be a bus stop
        Part.PARKED_CAR: (10, 11, 111),
        Part.CURB: (20, 42, 423),
        Part.SIDEWALK: (48, 42, 422),
        Part.ROAD: (40, 42, 421),
        Part.WALKING_ADULT: (30, 21, 211),  # 254 would be a mailbox
        Part.KID: (16, 22, 221),
        Part.GRASS: (72, 93, 931),
    }
    for part, codes in expected.items():
        m = frame.part == part
        assert m.any(), part
        found = np.unique(np.column_stack([sem[m], orig[m], subl[m]]), axis=0)
        assert found.tolist() == [list(codes)], part
    assert 252 not in sem and 254 not in sem


def test_voxelscape_intensity_is_continuous_physics_in_unit_interval(voxel_tree):
    root, _ = voxel_tree
    scan = np.fromfile(root / "00/velodyne/xyz_iom_000000.bin", dtype="<f4").reshape(-1, 4)
    frame = next(synth_frames("hdl64e", frames=1, seed=0))
    assert np.array_equal(scan[:, :3], frame.xyz)
    i = scan[:, 3]
    assert 0.0 <= i.min() and i.max() <= 0.9999  # the voxelscape64 profile's range
    assert len(np.unique(i)) > 10_000  # not quantised to a 0.01 grid
    assert np.allclose(i, np.clip(frame.reflectivity, 0, 0.9999), atol=1e-6)


def test_voxelscape_code_table_matches_the_documented_examples():
    ids = voxelscape_ids()
    assert len(ids.classes) == 32
    assert ids.classes[12] == "bus" and ids.classes[21] == "adult"
    assert all("building" in ids.classes[c] for c in range(30, 35))
    assert "terrain" in ids.classes[41] and "terrain" in ids.classes[93]
    assert [ids.sublabels[s][0] for s in (421, 422, 423)] == ["road", "sidewalk", "curb"]
    assert ids.sublabels[111] == ("car-body", 10)  # moving or not: 252 is a bus stop there


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    trees = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        write_synthetic_dataset(tmp_path / name, frames=2, seed=seed, azimuth_bins=512)
        trees.append({f: (tmp_path / name / f).read_bytes() for f in _tree_files(tmp_path / name)})
    assert trees[0] == trees[1]
    scan = "sequences/00/velodyne/000001.bin"
    assert trees[0][scan] != trees[2][scan]


def test_a_short_sequence_is_the_prefix_of_a_longer_one():
    short = list(synth_frames("hdl32e", frames=2, seed=3))
    long = list(synth_frames("hdl32e", frames=4, seed=3))
    for a, b in zip(short, long[:2], strict=True):
        assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.labels, b.labels)
        assert np.array_equal(a.intensity, b.intensity) and np.array_equal(a.pose, b.pose)


@pytest.mark.parametrize("sensor", ["hdl64e", "hdl32e"])
def test_intensities_lie_exactly_on_the_profile_encoding_grid(sensor):
    profile = load_profile(sensor)
    frame = next(synth_frames(profile, frames=1, seed=1))
    i = frame.intensity
    assert i.dtype == np.float32 and len(np.unique(i)) > 20
    if profile.intensity.kind == "unit":  # KITTI: float32(k / 100), k = 0..99
        grid = (np.arange(100) / 100).astype(np.float32)
    else:  # nuScenes: integer floats 0-255
        grid = np.arange(256, dtype=np.float32)
    assert np.isin(i, grid).all()
    profile.intensity.validate(i, f"synthetic {sensor} frame")  # raises if out of range


def test_every_promised_class_appears_within_five_frames(frames5):
    present = set().union(*(np.unique(f.labels & 0xFFFF).tolist() for f in frames5))
    missing = {name for name, cid in PROMISED.items() if cid not in present}
    assert not missing


def test_instances_mark_exactly_cars_and_people_and_persist_across_frames(frames5):
    per_frame = []
    for f in frames5:
        sem, inst = f.labels & 0xFFFF, f.labels >> 16
        assert set(np.unique(sem[inst > 0])) <= THINGS
        assert (inst[np.isin(sem, list(THINGS))] > 0).all()
        ids = np.unique(inst[inst > 0])
        assert all(len(np.unique(sem[inst == i])) == 1 for i in ids)  # one class per instance
        per_frame.append(set(ids.tolist()))
    assert len(per_frame[0] & per_frame[-1]) >= 0.7 * len(per_frame[0])


def test_moving_cars_move_in_the_world_and_parked_cars_do_not(frames5):
    def centroids(frame, cls):
        world, sem, inst = _world(frame), frame.labels & 0xFFFF, frame.labels >> 16
        return {
            int(i): world[inst == i, :2].mean(axis=0)
            for i in np.unique(inst[sem == cls])
            if (inst == i).sum() >= 50
        }

    first, last = frames5[0], frames5[-1]
    for cls, lo, hi in ((252, 1.5, 8.0), (10, 0.0, 0.5)):
        a, b = centroids(first, cls), centroids(last, cls)
        shifts = [np.linalg.norm(a[i] - b[i]) for i in a.keys() & b.keys()]
        assert len(shifts) >= 2, cls
        assert lo < np.median(shifts) < hi, (cls, shifts)


def test_poses_advance_about_one_metre_per_frame_at_10_hz(frames5):
    positions = np.array([f.pose[:3, 3] for f in frames5])
    assert np.allclose(np.linalg.norm(np.diff(positions, axis=0), axis=1), 1.0, atol=0.02)
    assert np.allclose(positions[:, 2], 1.73)
    assert [f.time_s for f in frames5] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    for f in frames5:
        assert np.allclose(f.pose[:3, :3] @ f.pose[:3, :3].T, np.eye(3))
        assert f.pose.dtype == np.float64 and np.array_equal(f.pose[3], [0, 0, 0, 1])


def test_points_are_stored_ring_by_ring_top_first_in_azimuth_order(frames5):
    f = frames5[0]
    assert f.ring[0] == 63 and f.ring[-1] == 0
    assert (np.diff(f.ring) <= 0).all()
    azimuth = np.mod(np.arctan2(f.xyz[:, 1], f.xyz[:, 0]), 2 * np.pi)
    same_ring = np.diff(f.ring) == 0
    assert (np.diff(azimuth)[same_ring] > -1e-3).all()
    assert np.array_equal(rings_from_scan_order(f.xyz, 64), f.ring)


def test_frames_have_kitti_like_statistics(frames5):
    profile = load_profile("hdl64e")
    for f in frames5:
        n = f.xyz.shape[0]
        assert 60_000 < n <= 64 * 2048
        assert f.xyz.dtype == np.float32 and f.labels.dtype == np.uint32
        assert f.ring.dtype == np.int64 and f.intensity.shape == (n,) == f.labels.shape
        r = np.linalg.norm(f.xyz, axis=1)
        assert profile.min_range_m <= r.min() and r.max() <= profile.max_range_m
        assert 5.0 < np.median(r) < 30.0  # KITTI frame 00/000000: median 10 m
        road = (f.labels & 0xFFFF) == 40
        assert abs(np.median(f.xyz[road, 2]) + 1.73) < 0.02  # ground 1.73 m below the sensor
        assert np.std(_world(f)[road, 2]) < 0.03  # flat, with cm range noise


def test_errors_name_the_problem(tmp_path):
    with pytest.raises(ConfigError, match="layout 'kitti'"):
        write_synthetic_dataset(tmp_path, layout="kitti")
    with pytest.raises(ConfigError, match="frames=0"):
        write_synthetic_dataset(tmp_path, frames=0)
    with pytest.raises(SensorProfileError, match="not found"):
        write_synthetic_dataset(tmp_path, sensor="hdl999")
    write_synthetic_dataset(tmp_path, frames=2, azimuth_bins=256)
    with pytest.raises(ConfigError, match="000001.bin"):  # stale frame from the longer run
        write_synthetic_dataset(tmp_path, frames=1, azimuth_bins=256)
    assert not list(tmp_path.rglob("*.tmp"))


def test_synth_command_writes_a_tree_and_maps_errors_to_usage(tmp_path):
    out = tmp_path / "vs"
    args = ["--sensor", "hdl32e", "--frames", "2", "--layout", "voxelscape", "--out", str(out)]
    result = CliRunner().invoke(synth_command, [*args, "--sequence", "07", "--seed", "2"])
    assert result.exit_code == 0, result.output
    assert re.search(r"2 voxelscape frames .*hdl32e", result.output)
    assert (out / "07/orig_labels/xyz_iom_000001_subl.label").is_file()
    bad = CliRunner().invoke(synth_command, ["--frames", "0", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "frames=0" in bad.output
    bad = CliRunner().invoke(synth_command, ["--sensor", "nope", "--out", str(tmp_path / "y")])
    assert bad.exit_code == 2 and "not found" in bad.output


# ----------------------------------------------------------------------------------------
# nuScenes layout

NUSC_LABELS = {  # SemanticKITTI raw id -> nuScenes lidarseg index (category.json `index`)
    10: 17, 252: 17, 30: 2, 254: 2, 40: 24, 60: 24, 48: 26, 72: 27,
    50: 28, 51: 28, 80: 28, 81: 28, 70: 30, 71: 30, 0: 0,
}  # fmt: skip


def _nusc_scans(root):
    return sorted((root / "samples/LIDAR_TOP").glob("*.pcd.bin"))


def test_nuscenes_tree_loads_with_the_devkit(nusc_tree):
    from nuscenes.nuscenes import NuScenes
    from nuscenes.utils.data_classes import LidarPointCloud
    from nuscenes.utils.data_io import load_bin_file
    from PIL import Image

    root, summary = nusc_tree
    assert (summary.layout, summary.sensor, summary.frames) == ("nuscenes", "hdl32e", 3)
    assert summary.files == tuple(_tree_files(root))
    tables = {f"v1.0-mini/{t}.json" for t in (*TABLES, "lidarseg")}
    assert tables == {f for f in summary.files if f.startswith("v1.0-mini/")}
    nusc = NuScenes("v1.0-mini", dataroot=str(root), verbose=False)
    assert len(nusc.lidarseg) == len(nusc.sample) == len(nusc.sample_data) == 3
    (scene,) = nusc.scene
    assert scene["nbr_samples"] == 3 and scene["name"] == "scene-0000"
    sample, stamps, counts = nusc.get("sample", scene["first_sample_token"]), [], []
    while True:  # samples linked prev/next, each with its LIDAR_TOP keyframe
        sd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
        assert sd["is_key_frame"] and sd["fileformat"] == "pcd"
        assert sd["filename"].startswith("samples/LIDAR_TOP/n000-")
        rec = nusc.get("lidarseg", sd["token"])
        assert rec["filename"] == f"lidarseg/v1.0-mini/{sd['token']}_lidarseg.bin"
        pc = LidarPointCloud.from_file(str(root / sd["filename"]))
        labels = load_bin_file(str(root / rec["filename"]), "lidarseg")
        assert pc.points.shape == (4, labels.size) and labels.dtype == np.uint8
        stamps.append(sd["timestamp"])
        counts.append(labels.size)
        if not sample["next"]:
            break
        assert nusc.get("sample", sample["next"])["prev"] == sample["token"]
        sample = nusc.get("sample", sample["next"])
    assert sample["token"] == scene["last_sample_token"]
    assert np.diff(stamps).tolist() == [500_000, 500_000]  # keyframes at 2 Hz
    assert counts == list(summary.points_per_frame)
    assert [(c["index"], c["name"]) for c in nusc.category] == [
        (i, name) for i, (name, _) in sorted(class_materials("nuscenes").items())
    ]
    assert nusc.lidarseg_name2idx_mapping["vehicle.car"] == 17
    (map_rec,) = nusc.map
    assert map_rec["log_tokens"] == [nusc.log[0]["token"]]
    assert Image.open(root / map_rec["filename"]).size == (1, 1)


def test_nuscenes_scans_are_the_frames_in_lidar_top_axes(nusc_tree, frames32):
    root, _ = nusc_tree
    channels = load_profile("hdl32e").channels
    for path, frame in zip(_nusc_scans(root), frames32, strict=True):
        scan = np.fromfile(path, dtype="<f4").reshape(-1, 5)
        assert scan.shape[0] == frame.xyz.shape[0]
        # x right, y forward: x_n = -y, y_n = x, exactly
        assert np.array_equal(
            scan[:, :3], np.column_stack([-frame.xyz[:, 1], frame.xyz[:, 0], frame.xyz[:, 2]])
        )
        ring, intensity = scan[:, 4], scan[:, 3]
        assert np.array_equal(ring, np.round(ring)) and np.array_equal(ring, frame.ring)
        assert 0 <= ring.min() and ring.max() <= channels - 1
        assert len(np.unique(ring)) == channels
        assert np.array_equal(intensity, np.round(intensity))
        assert 0 <= intensity.min() and intensity.max() <= 255 and len(np.unique(intensity)) > 20
        assert np.array_equal(intensity, frame.intensity)  # the hdl32e byte encoding
        load_profile("hdl32e").intensity.validate(intensity, path.name)


def test_nuscenes_labels_map_semantickitti_ids_to_lidarseg_indices(nusc_tree, frames32):
    root, _ = nusc_tree
    reader = NuScenesReader(root)
    for item, frame in zip(reader.items(), frames32, strict=True):
        labels = np.fromfile(root / item.label_relpath, dtype=np.uint8)
        sem = frame.labels & 0xFFFF
        assert labels.size == sem.size
        for raw, index in NUSC_LABELS.items():
            assert (labels[sem == raw] == index).all(), raw
        assert set(np.unique(sem).tolist()) <= set(NUSC_LABELS)
    classes = lidarseg_classes()
    assert len(classes.categories) == 32 and classes.categories[31] == "vehicle.ego"
    assert classes.labels(np.array([(7 << 16) | 252, 48, 999], dtype=np.uint32)).tolist() == [
        17,
        26,
        0,
    ]


def test_nuscenes_poses_put_points_where_the_frame_has_them(nusc_tree, frames32):
    from nuscenes.nuscenes import NuScenes
    from nuscenes.utils.data_classes import LidarPointCloud
    from pyquaternion import Quaternion

    root, _ = nusc_tree
    nusc = NuScenes("v1.0-mini", dataroot=str(root), verbose=False)
    sds = sorted(nusc.sample_data, key=lambda sd: sd["timestamp"])
    for sd, frame in zip(sds, frames32, strict=True):
        cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
        ego = nusc.get("ego_pose", sd["ego_pose_token"])
        assert cs["translation"] == list(SENSOR_TRANSLATION)
        assert ego["translation"][2] == 0.0  # the ego frame sits on the road
        pc = LidarPointCloud.from_file(str(root / sd["filename"]))
        for record in (cs, ego):  # sensor -> ego -> global, as the devkit does it
            pc.rotate(Quaternion(record["rotation"]).rotation_matrix)
            pc.translate(np.array(record["translation"]))
        np.testing.assert_allclose(pc.points[:3].T, _world(frame), atol=1e-3)


def test_quaternions_match_pyquaternion():
    from pyquaternion import Quaternion

    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        rot = Quaternion(q / np.linalg.norm(q)).rotation_matrix
        got = Quaternion(quaternion_wxyz(rot))
        assert got.w >= 0 and np.allclose(got.rotation_matrix, rot, atol=1e-12)
    assert quaternion_wxyz(np.eye(3)) == (1.0, 0.0, 0.0, 0.0)


def test_nuscenes_reader_round_trips_the_tree_byte_for_byte(nusc_tree):
    root, summary = nusc_tree
    reader = NuScenesReader(root)
    items = reader.items()
    assert len(items) == summary.frames
    for item in items:
        token = dict(item.meta)["sample_data_token"]
        assert item.label_relpath == f"lidarseg/v1.0-mini/{token}_lidarseg.bin"
        frame = reader.read(item)
        assert frame.points.shape[1] == 5 and frame.labels.shape == (frame.points.shape[0],)
        for encoded in reader.encode(frame):
            assert encoded.payload == (root / encoded.relpath).read_bytes(), encoded.relpath
    assert set(reader.copied_files()) == {f for f in summary.files if f.startswith(("v1", "maps"))}


def test_nuscenes_same_seed_same_bytes_and_stale_files_refused(tmp_path):
    trees = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        out = tmp_path / name
        write_synthetic_dataset(out, frames=2, seed=seed, layout="nuscenes", azimuth_bins=256)
        trees.append({f: (out / f).read_bytes() for f in _tree_files(out)})
    assert trees[0] == trees[1]
    assert trees[0].keys() != trees[2].keys()  # other tokens
    scans = [{k: v for k, v in t.items() if k.startswith("samples/")} for t in trees]
    assert scans[0].keys() == scans[2].keys() and scans[0] != scans[2]
    with pytest.raises(ConfigError, match="_lidarseg.bin"):  # another seed's label files
        write_synthetic_dataset(
            tmp_path / "a", frames=2, seed=6, layout="nuscenes", azimuth_bins=256
        )


def test_nuscenes_default_sensor_is_hdl32e_and_any_profile_works(tmp_path):
    default = write_synthetic_dataset(tmp_path / "d", frames=1, layout="nuscenes", azimuth_bins=64)
    assert default.sensor == "hdl32e"
    assert write_synthetic_dataset(tmp_path / "k", frames=1, azimuth_bins=64).sensor == "hdl64e"
    summary = write_synthetic_dataset(
        tmp_path / "n", sensor="hdl64e", frames=1, layout="nuscenes", azimuth_bins=64
    )
    scan = np.fromfile(_nusc_scans(tmp_path / "n")[0], dtype="<f4").reshape(-1, 5)
    assert summary.sensor == "hdl64e" and scan[:, 4].max() == 63  # ring = channel index
    intensity = scan[:, 3]  # the HDL-64E's own remission: read the tree with that sensor
    assert intensity.max() <= np.float32(0.99)
    assert not np.array_equal(intensity, np.round(intensity))
    assert len(NuScenesReader(tmp_path / "n").items()) == 1
    reader = get_reader("nuscenes", tmp_path / "n", sensor="hdl64e")
    assert reader.read(reader.items()[0]).points.shape == scan.shape


def test_a_voxelscape_street_of_a_named_sensor_holds_its_encoding(tmp_path):
    """Without --sensor, Voxelscape's own continuous reflectivity; with one, that sensor's
    values, so `lads build --sensor S` reads what `lads synth --sensor S` wrote."""
    for sensor in ("hdl32e", "hdl64e"):
        write_synthetic_dataset(tmp_path / sensor, sensor=sensor, frames=1, layout="voxelscape")
        reader = get_reader("voxelscape", tmp_path / sensor, sensor=sensor)
        values = reader.read(reader.items()[0]).intensity
        step = load_profile(sensor).intensity.step
        assert np.allclose(values / step, np.rint(values / step), atol=1e-3)


def test_synth_command_writes_a_nuscenes_tree(tmp_path):
    out = tmp_path / "nusc"
    args = ["--frames", "1", "--layout", "nuscenes", "--out", str(out), "--sequence", "3"]
    result = CliRunner().invoke(synth_command, args)
    assert result.exit_code == 0, result.output
    assert re.search(r"1 nuscenes frames .*hdl32e", result.output)
    assert json.loads((out / "v1.0-mini/scene.json").read_text())[0]["name"] == "scene-0003"


def test_synthetic_release_table_has_every_source_and_variant(tmp_path):
    table = synthetic_table(tmp_path, frames=2, seed=0)
    assert len(table) == 6
    assert [e.source for e in table[::2]] == ["semantickitti", "nuscenes", "voxelscape"]
    assert [e.variant for e in table] == list(RELEASE_VARIANTS) * 3
    assert [e.name for e in table[2:4]] == ["nuscenes-snow", "nuscenes-rain"]
    assert table[2].root == tmp_path / "sources" / "synthetic-nuscenes"
    assert len(NuScenesReader(table[2].root).items()) == 2


def test_the_writer_creates_the_items_of_each_reader_and_their_encoded_bytes(
    kitti_tree, voxel_tree, nusc_tree
):
    """Each file of a frame is named by its reader's `new_item` and is what its `encode`
    gives: listing the tree gives those items, and read -> encode reproduces every file."""
    kitti_root, voxel_root, nusc_root = kitti_tree[0], voxel_tree[0], nusc_tree[0]
    kitti = SemanticKittiReader(kitti_root)
    assert kitti.items() == [kitti.new_item("04", k) for k in range(3)]
    assert kitti.copied_files() == [kitti.sequence_file("04", n) for n in kitti.copied_names]
    voxel = VoxelscapeReader(voxel_root)
    assert voxel.items() == [voxel.new_item("00", k) for k in range(2)]
    nusc = NuScenesReader(nusc_root)
    listed = nusc.items()
    expected = [
        nusc.new_item(
            nusc.keyframe_filename(NUSC_LOG, NUSC_T0_US + NUSC_KEYFRAME_US * k),
            dict(it.meta)["sample_data_token"],
            "v1.0-mini",
        )
        for k, it in enumerate(listed)
    ]
    assert [replace(it, meta=new.meta) for it, new in zip(listed, expected, strict=True)] == (
        expected
    )
    for reader, root in ((kitti, kitti_root), (voxel, voxel_root), (nusc, nusc_root)):
        for item in reader.items():
            for encoded in reader.encode(reader.read(item)):
                assert encoded.payload == (root / encoded.relpath).read_bytes()


def test_a_release_root_without_the_release_sequences_is_one_line_and_exit_2(
    tmp_path, monkeypatch, capsys
):
    from lads.release import main as release_main

    write_synthetic_dataset(tmp_path / "kitti", frames=1)  # sequence 00 only
    monkeypatch.setenv("LADS_SEMANTICKITTI_ROOT", str(tmp_path / "kitti"))
    monkeypatch.setenv("LADS_RELEASE_OUT", str(tmp_path / "release"))
    assert release_main([]) == 2
    err = capsys.readouterr().err
    assert err.startswith("make release: error:") and "not found" in err and "Traceback" not in err
