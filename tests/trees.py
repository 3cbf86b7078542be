"""Small dataset trees for tests, built in a given (temporary) directory.

Two kinds, one function per dataset format each:

- `synthetic_*`: random points written in the format (float32 binaries, CSV text, nuScenes
  tables), with the traps of docs/formats.md built in: exact-duplicate rows, near-origin points,
  unlabelled sequences, Voxelscape's three label files.
- `real_*`: the real sample files of ../shared/data, **symlinked** (never copied into the
  repository) into the layout the reader expects; only generated files (e.g. a label file for
  the full nuScenes keyframe, the nuScenes JSON tables) are written for real.

Every function returns the root to hand to the reader.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks.common import SHARED_DATA

# The nuScenes tables come from the package (one implementation); tests use trees.token and
# trees.NuscSampleData as before.
from lads.synth.nuscenes import NuscSampleData, lidarseg_classes, nuscenes_tables, token

KITTI_GRID = (np.arange(100, dtype=np.float64) * 0.01).astype(np.float32)  # 0.00..0.99

# lidarseg category order of the data and devkit (docs/formats.md §2.3); `index` = position.
NUSCENES_CATEGORIES = lidarseg_classes().categories


def _write(path: Path, payload: bytes | str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(payload, str):
        payload = payload.encode()
    path.write_bytes(payload)
    return path


def _link(target: Path, link: Path) -> Path:
    if not target.is_file():
        raise FileNotFoundError(f"real sample {target} not found")
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(target)
    return link


def synthetic_points(
    rng: np.random.Generator, n: int, *, intensity: str, ring: bool = False
) -> np.ndarray:
    """(n, 4 or 5) float32 scan rows with ~20 % exact duplicates and a few near-origin points.

    intensity: "unit" (0.01 grid, 0-0.99), "byte" (integers 0-255) or "continuous" ([0, 0.9)).
    """
    xyz = rng.normal(0.0, 15.0, (n, 3))
    xyz[: max(1, n // 20)] = rng.normal(0.0, 0.3, (max(1, n // 20), 3))  # near the sensor
    if intensity == "unit":
        inten = KITTI_GRID[rng.integers(0, 100, n)].astype(np.float64)
    elif intensity == "byte":
        inten = rng.integers(0, 256, n).astype(np.float64)
    else:  # continuous, inside the voxelscape64 profile's [0, 0.9999]
        inten = rng.uniform(0.0, 0.9, n)
    cols = [xyz, inten[:, None]]
    if ring:
        cols.append(rng.integers(0, 32, n).astype(np.float64)[:, None])
    points = np.hstack(cols).astype(np.float32)
    dup = rng.choice(n, size=n // 5, replace=False)
    points[dup] = points[rng.integers(0, n, dup.size)]  # exact duplicate rows
    return points


# ----------------------------------------------------------------------------------------
# SemanticKITTI and WADS


def synthetic_semantickitti(
    root: Path,
    *,
    sequences: dict[str, int] | None = None,
    labelled: tuple[str, ...] = ("00", "01"),
    points: tuple[int, int] = (40, 160),
    intensity: str = "unit",
    copied: tuple[str, ...] = ("calib.txt", "poses.txt", "times.txt"),
    seed: int = 0,
) -> Path:
    """`root/sequences/SS/velodyne/NNNNNN.bin` (+ labels/ for `labelled`, + copied txt files).

    Default sequences {"00": 3, "01": 2, "11": 2}; 11 has no labels/ (a test sequence).
    Labels are uint32 `instance << 16 | semantic`.
    """
    rng = np.random.default_rng(seed)
    sequences = sequences if sequences is not None else {"00": 3, "01": 2, "11": 2}
    for seq, count in sequences.items():
        base = root / "sequences" / seq
        for i in range(count):
            n = int(rng.integers(*points))
            pts = synthetic_points(rng, n, intensity=intensity)
            _write(base / "velodyne" / f"{i:06d}.bin", pts.astype("<f4").tobytes())
            if seq in labelled:
                sem = rng.choice([0, 1, 10, 40, 48, 50, 70, 110, 252], n).astype(np.uint32)
                inst = rng.integers(0, 300, n).astype(np.uint32)
                labels = (inst << np.uint32(16)) | sem
                _write(base / "labels" / f"{i:06d}.label", labels.astype("<u4").tobytes())
        if "calib.txt" in copied:
            _write(
                base / "calib.txt",
                "".join(f"P{k}: " + " ".join(["0.0"] * 12) + "\n" for k in range(4))
                + "Tr: "
                + " ".join(["1.0"] * 12)
                + "\n",
            )
        if "poses.txt" in copied:
            _write(base / "poses.txt", "".join(" ".join(["1.0"] * 12) + "\n" for _ in range(count)))
        if "times.txt" in copied:
            _write(base / "times.txt", "".join(f"{0.1 * i:e}\n" for i in range(count)))
    return root


def synthetic_wads(root: Path, *, seed: int = 1, **kwargs) -> Path:
    """WADS: SemanticKITTI layout, intensity integers 0-255; sequences {"36": 3, "11": 1}."""
    kwargs.setdefault("sequences", {"36": 3, "11": 1})
    kwargs.setdefault("labelled", ("36",))
    return synthetic_semantickitti(root, intensity="byte", seed=seed, **kwargs)


def _real_kitti_layout(
    root: Path, source: Path, seq: str, frames: list[str], extra: tuple[str, ...]
) -> Path:
    base = root / "sequences" / seq
    for stem in frames:
        _link(source / "velodyne" / f"{stem}.bin", base / "velodyne" / f"{stem}.bin")
        _link(source / "labels" / f"{stem}.label", base / "labels" / f"{stem}.label")
    for name in extra:
        _link(source / name, base / name)
    return root


def real_semantickitti(root: Path) -> Path:
    """The 3 real SemanticKITTI frames of sequence 00 with labels, calib.txt and times.txt."""
    src = SHARED_DATA / "semantickitti" / "sequences" / "00"
    return _real_kitti_layout(
        root, src, "00", ["000000", "000001", "000002"], ("calib.txt", "times.txt")
    )


def real_wads(root: Path) -> Path:
    """The 3 real WADS frames of sequence 36 (≈42 % duplicate rows) with labels."""
    src = SHARED_DATA / "wads" / "sequences" / "36"
    return _real_kitti_layout(root, src, "36", ["042223", "042224", "042225"], ())


# ----------------------------------------------------------------------------------------
# Voxelscape


def synthetic_voxelscape(
    root: Path,
    *,
    sequences: dict[str, int] | None = None,
    kitti_labels: bool = True,
    orig_labels: bool = True,
    sublabels: bool = True,
    bboxs: bool = True,
    seed: int = 2,
) -> Path:
    """`root/SS/velodyne/xyz_iom_NNNNNN.bin`, `kitti_labels/` uint32, `orig_labels/` int32
    (+ `_subl` int32), `bboxs/*.pkl` placeholders. Default sequences {"00": 2, "01": 2}."""
    rng = np.random.default_rng(seed)
    sequences = sequences if sequences is not None else {"00": 2, "01": 2}
    for seq, count in sequences.items():
        base = root / seq
        for i in range(count):
            stem = f"xyz_iom_{i:06d}"
            n = int(rng.integers(30, 120))
            pts = synthetic_points(rng, n, intensity="continuous")
            _write(base / "velodyne" / f"{stem}.bin", pts.astype("<f4").tobytes())
            if kitti_labels:
                lab = rng.choice([0, 1, 16, 20, 30, 40, 252, 259], n).astype("<u4")
                _write(base / "kitti_labels" / f"{stem}.label", lab.tobytes())
            if orig_labels:
                orig = rng.integers(-1, 94, n).astype("<i4")
                _write(base / "orig_labels" / f"{stem}.label", orig.tobytes())
            if sublabels:
                subl = rng.integers(-1, 500, n).astype("<i4")
                _write(base / "orig_labels" / f"{stem}_subl.label", subl.tobytes())
            if bboxs:
                _write(base / "bboxs" / f"{stem}.pkl", b"\x80\x04]\x94.")  # pickle of []
    return root


# ----------------------------------------------------------------------------------------
# RADIATE


def radiate_csv(points: np.ndarray) -> bytes:
    """RADIATE text: `%.5g` per value, ',' separated, one '\\n'-terminated line per point."""
    return "".join(
        ",".join(f"{float(v):.5g}" for v in row) + "\n" for row in points.astype(np.float64)
    ).encode()


def synthetic_radiate(
    root: Path, *, sequences: dict[str, int] | None = None, seed: int = 3
) -> Path:
    """`root/<seq>/velo_lidar/NNNNNN.csv` (+ velo_lidar.txt, meta.json); default
    {"fog_1": 3, "rain_2": 2}. Coordinates carry 5 significant digits like the real files."""
    rng = np.random.default_rng(seed)
    sequences = sequences if sequences is not None else {"fog_1": 3, "rain_2": 2}
    for seq, count in sequences.items():
        base = root / seq
        lines = []
        for i in range(count):
            n = int(rng.integers(30, 120))
            pts = synthetic_points(rng, n, intensity="byte", ring=True)
            pts[:, :3] = np.array(
                [f"{v:.5g}" for v in pts[:, :3].ravel()], dtype=np.float64
            ).reshape(-1, 3)
            pts[:3, 1] = [0.00023476, -0.0024364, 12.0]  # small values and an integer coordinate
            _write(base / "velo_lidar" / f"{i:06d}.csv", radiate_csv(pts))
            lines.append(f"Frame: {i:06d} Time: {1574859771.7 + 0.1 * i:.9f}\n")
        _write(base / "velo_lidar.txt", "".join(lines))
        _write(base / "meta.json", json.dumps({"name": seq, "type": "fog"}))
    return root


def real_radiate(root: Path) -> Path:
    """The 3 real RADIATE fog frames (sequence tiny_foggy) with velo_lidar.txt and meta.json."""
    src = SHARED_DATA / "radiate" / "tiny_foggy"
    for stem in ("000018", "000019", "000020"):
        _link(
            src / "velo_lidar" / f"{stem}.csv", root / "tiny_foggy" / "velo_lidar" / f"{stem}.csv"
        )
    for name in ("velo_lidar.txt", "meta.json"):
        _link(src / name, root / "tiny_foggy" / name)
    return root


# ----------------------------------------------------------------------------------------
# nuScenes


def write_nuscenes_tables(root: Path, version: str, records: list[NuscSampleData]) -> Path:
    """The tables of `lads.synth.nuscenes.nuscenes_tables` (13 tables, lidarseg.json /
    panoptic.json when any record has labels, a one-log one-scene database with the real
    LIDAR_TOP calibration) and its map PNG, written under `root`."""
    for rel, payload in nuscenes_tables(version, records).items():
        _write(root / rel, payload)
    return root


def synthetic_nuscenes(
    root: Path,
    *,
    version: str = "v1.0-mini",
    keyframes: int = 3,
    sweeps: int = 2,
    panoptic: bool = False,
    seed: int = 4,
) -> Path:
    """A nuScenes dataroot: `keyframes` labelled LIDAR_TOP samples (N x 5 float32 with ring,
    uint8 lidarseg, optionally uint16 panoptic npz via np.savez_compressed), `sweeps`
    unlabelled sweeps, and the tables of `write_nuscenes_tables`."""
    rng = np.random.default_rng(seed)
    log = "n015-2018-07-24-11-22-45+0800"
    records = []
    t0 = 1532402927647951
    for i in range(keyframes + sweeps):
        key = i < keyframes
        stamp = t0 + 500_000 * i + (0 if key else 250_000)
        folder = "samples" if key else "sweeps"
        filename = f"{folder}/LIDAR_TOP/{log}__LIDAR_TOP__{stamp}.pcd.bin"
        n = int(rng.integers(40, 160))
        pts = synthetic_points(rng, n, intensity="byte", ring=True)
        _write(root / filename, pts.astype("<f4").tobytes())
        tok = token(filename)
        seg = pan = None
        if key:
            labels = rng.integers(0, 32, n).astype(np.uint8)
            seg = f"lidarseg/{version}/{tok}_lidarseg.bin"
            _write(root / seg, labels.tobytes())
            if panoptic:
                pan = f"panoptic/{version}/{tok}_panoptic.npz"
                (root / pan).parent.mkdir(parents=True, exist_ok=True)
                data = (labels.astype(np.uint16) * 1000 + rng.integers(0, 40, n)).astype(np.uint16)
                np.savez_compressed(root / pan, data=data)
        records.append(NuscSampleData(tok, filename, key, seg, pan))
    return write_nuscenes_tables(root, version, records)


NUSC_TINY_SAMPLE = (
    "samples/LIDAR_TOP/n015-2018-08-02-17-16-37+0800__LIDAR_TOP__1533201470948018.pcd.bin"
)
NUSC_TINY_TOKEN = "5f6c1e0a0c3b444b97e78d2aa3fa34d2"  # its real lidarseg file's token
NUSC_TINY_SWEEP = (
    "sweeps/LIDAR_TOP/n015-2018-08-02-17-16-37+0800__LIDAR_TOP__1533201470898274.pcd.bin"
)
NUSC_FULL_SAMPLE = (
    "samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"
)


def real_nuscenes(root: Path, version: str = "v1.0-mini") -> Path:
    """A minimal real nuScenes dataroot with two keyframes and one sweep:

    - the real 40-point nuscenes-tiny keyframe with its real lidarseg file;
    - the full real keyframe (34,688 points) with a generated uint8 label file (31 ego within
      1.1 m, 24 driveable surface below -1.5 m, 28 manmade elsewhere);
    - the real nuscenes-tiny sweep of the same log (100 points, no labels);

    around JSON tables from `write_nuscenes_tables`.
    """
    tiny, full = SHARED_DATA / "nuscenes-tiny", SHARED_DATA / "nuscenes"
    _link(tiny / NUSC_TINY_SAMPLE, root / NUSC_TINY_SAMPLE)
    tiny_seg = f"lidarseg/{version}/{NUSC_TINY_TOKEN}_lidarseg.bin"
    _link(tiny / "lidarseg" / "v1.0-trainval" / f"{NUSC_TINY_TOKEN}_lidarseg.bin", root / tiny_seg)
    _link(tiny / NUSC_TINY_SWEEP, root / NUSC_TINY_SWEEP)
    _link(full / NUSC_FULL_SAMPLE, root / NUSC_FULL_SAMPLE)
    pts = np.fromfile(full / NUSC_FULL_SAMPLE, dtype="<f4").reshape(-1, 5)
    r = np.linalg.norm(pts[:, :3], axis=1)
    labels = np.where(r < 1.1, 31, np.where(pts[:, 2] < -1.5, 24, 28)).astype(np.uint8)
    full_token = token(NUSC_FULL_SAMPLE)
    full_seg = f"lidarseg/{version}/{full_token}_lidarseg.bin"
    _write(root / full_seg, labels.tobytes())
    records = [
        NuscSampleData(NUSC_TINY_TOKEN, NUSC_TINY_SAMPLE, True, tiny_seg),
        NuscSampleData(full_token, NUSC_FULL_SAMPLE, True, full_seg),
        NuscSampleData(token(NUSC_TINY_SWEEP), NUSC_TINY_SWEEP, False),
    ]
    return write_nuscenes_tables(root, version, records)


def synthetic_nuscenes_kitti(
    root: Path,
    *,
    scenes: dict[str, int] | None = None,
    labelled: tuple[str, ...] = ("train/0001", "train/0002"),
    seed: int = 5,
) -> Path:
    """nuScenes keyframes in the KITTI-style export: `<split>/<scene>/velodyne/NNNNNN.bin`
    (N x 4 float32, intensity integers 0-255), `sem_labels/NNNNNN.label` (uint8 0-31) for the
    `labelled` scenes, and `poses.txt`. Default scenes {"train/0001": 2, "train/0002": 1,
    "val/0003": 1}."""
    rng = np.random.default_rng(seed)
    scenes = scenes if scenes is not None else {"train/0001": 2, "train/0002": 1, "val/0003": 1}
    for scene, count in scenes.items():
        base = root / scene
        for i in range(count):
            n = int(rng.integers(40, 160))
            pts = synthetic_points(rng, n, intensity="byte")
            _write(base / "velodyne" / f"{i:06d}.bin", pts.astype("<f4").tobytes())
            if scene in labelled:
                labels = rng.integers(0, 32, n).astype(np.uint8)
                _write(base / "sem_labels" / f"{i:06d}.label", labels.tobytes())
        _write(base / "poses.txt", "".join(" ".join(["1.0"] * 12) + "\n" for _ in range(count)))
    return root


def synthetic_nuscenes_scans(
    root: Path, *, labelled: int = 2, loose: int = 2, seed: int = 6
) -> Path:
    """Loose nuScenes LIDAR_TOP scans: `data<i>/points.bin` + `ground.bin` (uint8 0-31) for
    `labelled` keyframes, and `loose` unlabelled `samples/LIDAR_TOP/<name>.pcd.bin` files,
    all N x 5 float32 with intensity integers 0-255 and ring 0-31."""
    rng = np.random.default_rng(seed)
    for i in range(labelled):
        n = int(rng.integers(40, 160))
        pts = synthetic_points(rng, n, intensity="byte", ring=True)
        _write(root / f"data{i}" / "points.bin", pts.astype("<f4").tobytes())
        _write(root / f"data{i}" / "ground.bin", rng.integers(0, 32, n).astype(np.uint8).tobytes())
    for i in range(loose):
        n = int(rng.integers(40, 160))
        pts = synthetic_points(rng, n, intensity="byte", ring=True)
        name = f"n015-2018-07-24-11-22-45+0800__LIDAR_TOP__15324029276{i:05d}.pcd.bin"
        _write(root / "samples" / "LIDAR_TOP" / name, pts.astype("<f4").tobytes())
    return root


def write_like_the_runner(reader, out: Path) -> None:
    """What the runner writes for a reader, without stages: copied files and encode(read())."""
    import shutil

    for rel in reader.copied_files():
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(reader.root / rel, out / rel)
    for item in reader.items():
        for e in reader.encode(reader.read(item)):
            (out / e.relpath).parent.mkdir(parents=True, exist_ok=True)
            (out / e.relpath).write_bytes(e.payload)
