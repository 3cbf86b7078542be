"""Every real frame of ../shared/data, wrapped into the source trees lads reads.

`REAL_SOURCES` names one tree per (reader, sample folder): its reader, the builder that lays
the real files out as that reader expects (symlinks, never copies; only generated files such
as nuScenes JSON tables are written), and the reader options. `real_scan_files()` lists
every scan file under ../shared/data, so a test can prove that the trees cover them all: a
real frame added to ../shared/data fails that test until a tree here takes it.

nuScenes tables are generated (no real v1.0 tables exist in the sample): one scene, made-up
timestamps 0.5 s apart and identity ego poses, around the real scans and real lidarseg files.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lads.synth.nuscenes import NuscSampleData, NuscScene, token
from tests.trees import (
    NUSC_FULL_SAMPLE,
    NUSC_TINY_SAMPLE,
    NUSC_TINY_SWEEP,
    SHARED_DATA,
    _link,
    _real_kitti_layout,
    real_nuscenes,
    real_radiate,
)

KITTI_SEQ00 = ("000000", "000001", "000002")
KITTI_MORE = ("000052", "000088", "000850", "004501")
KITTI_SEQ90 = ("000000", "000001", "000002", "000003", "000019")
WADS_FRAMES = tuple(f"0422{i}" for i in range(23, 34))
NUSC_SCENE_LOG = "n008-2018-05-21-11-06-59-0400"  # made-up log name for the generated tables
NUSC_SCENE_T0_US = 1526915243047392  # made-up first timestamp


def _stems(folder: Path, suffix: str) -> list[str]:
    return sorted(p.name[: -len(suffix)] for p in folder.glob(f"*{suffix}"))


def real_semantickitti_all(root: Path) -> Path:
    """Every labelled real SemanticKITTI frame: sequence 00 (000000-000002 with calib.txt
    and times.txt; 000052, 000088, 000850, 004501) and the placeholder sequence 90."""
    seq00 = SHARED_DATA / "semantickitti" / "sequences" / "00"
    _real_kitti_layout(root, seq00, "00", list(KITTI_SEQ00), ("calib.txt", "times.txt"))
    more = SHARED_DATA / "semantickitti-more" / "sequences" / "00"
    _real_kitti_layout(root, more, "00", list(KITTI_MORE), ())
    seq90 = SHARED_DATA / "semantickitti-seqx" / "sequences" / "90"
    return _real_kitti_layout(root, seq90, "90", list(KITTI_SEQ90), ())


def real_semantickitti_tiny(root: Path) -> Path:
    """The 50-point subset of frame 000000 (mmdetection3d's unit-test sample)."""
    src = SHARED_DATA / "semantickitti-tiny" / "sequences" / "00"
    return _real_kitti_layout(root, src, "00", ["000000"], ())


def real_wads_all(root: Path) -> Path:
    """The 11 real WADS frames of sequence 36, 042223-042233, with labels."""
    _real_kitti_layout(
        root, SHARED_DATA / "wads" / "sequences" / "36", "36", list(WADS_FRAMES[:3]), ()
    )
    return _real_kitti_layout(
        root, SHARED_DATA / "wads-more" / "sequences" / "36", "36", list(WADS_FRAMES[3:]), ()
    )


def real_nuscenes_scene0001(root: Path, version: str = "v1.0-trainval") -> Path:
    """The 40 labelled keyframes of nuScenes scene-0001 (5 columns, ring included) with their
    real lidarseg files, in a dataroot with generated tables."""
    src = SHARED_DATA / "nuscenes-scene0001"
    records = []
    for i in range(40):
        stamp = NUSC_SCENE_T0_US + 500_000 * i
        filename = f"samples/LIDAR_TOP/{NUSC_SCENE_LOG}__LIDAR_TOP__{stamp}.pcd.bin"
        _link(src / f"data{i}" / "points.bin", root / filename)
        tok = token(filename)
        seg = f"lidarseg/{version}/{tok}_lidarseg.bin"
        _link(src / f"data{i}" / "ground.bin", root / seg)
        records.append(NuscSampleData(tok, filename, True, seg))
    scene = NuscScene(logfile=NUSC_SCENE_LOG, name="scene-0001", salt="scene0001")
    for rel, payload in _tables(version, records, scene).items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(payload)
    return root


def _tables(version: str, records: list[NuscSampleData], scene: NuscScene) -> dict[str, bytes]:
    from lads.synth.nuscenes import nuscenes_tables

    return nuscenes_tables(version, records, scene)


def real_nuscenes_kitti(root: Path) -> Path:
    """The 40 labelled 4-column keyframes of nuScenes scene-0002 in the KITTI-style export
    (velodyne/, sem_labels/, poses.txt)."""
    src = SHARED_DATA / "nuscenes-kittifmt" / "train" / "0002"
    base = root / "train" / "0002"
    for stem in _stems(src / "velodyne", ".bin"):
        _link(src / "velodyne" / f"{stem}.bin", base / "velodyne" / f"{stem}.bin")
        _link(src / "sem_labels" / f"{stem}.label", base / "sem_labels" / f"{stem}.label")
    _link(src / "poses.txt", base / "poses.txt")
    return root


NUSC_LONE_SWEEP = (
    "nuscenes-tiny/sweeps/LIDAR_TOP/n008-2018-09-18-12-07-26-0400__LIDAR_TOP__1537287083900561"
    ".pcd.bin"
)
NUSC_SCANS_SCENE0001 = ("data0", "data39")  # two labelled keyframes, the scene's ends


def real_nuscenes_scans(root: Path) -> Path:
    """Loose nuScenes scans as users hold them without the tables: the full keyframe and the
    lone sweep (no table could hold it: its log has no keyframe here) as `.pcd.bin` files, and
    two labelled scene-0001 keyframes as `points.bin` + `ground.bin`."""
    full = SHARED_DATA / "nuscenes" / NUSC_FULL_SAMPLE
    _link(full, root / "samples" / "LIDAR_TOP" / full.name)
    sweep = SHARED_DATA / NUSC_LONE_SWEEP
    _link(sweep, root / "sweeps" / "LIDAR_TOP" / sweep.name)
    for folder in NUSC_SCANS_SCENE0001:
        for name in ("points.bin", "ground.bin"):
            _link(SHARED_DATA / "nuscenes-scene0001" / folder / name, root / folder / name)
    return root


@dataclass(frozen=True)
class RealSource:
    """One tree of real frames: reader name, builder, reader options, and the scan files of
    ../shared/data it holds (relative to ../shared/data, for the coverage test)."""

    reader: str
    build: Callable[[Path], Path]
    covers: Callable[[], list[str]]
    options: dict[str, Any] = field(default_factory=dict)


def _under(*folders: str, suffix: str) -> Callable[[], list[str]]:
    def files() -> list[str]:
        found = [p for folder in folders for p in (SHARED_DATA / folder).rglob(f"*{suffix}")]
        return sorted(p.relative_to(SHARED_DATA).as_posix() for p in found)

    return files


REAL_SOURCES: dict[str, RealSource] = {
    "semantickitti": RealSource(
        "semantickitti",
        real_semantickitti_all,
        _under("semantickitti", "semantickitti-more", "semantickitti-seqx", suffix=".bin"),
    ),
    "semantickitti-tiny": RealSource(
        "semantickitti", real_semantickitti_tiny, _under("semantickitti-tiny", suffix=".bin")
    ),
    "wads": RealSource("wads", real_wads_all, _under("wads", "wads-more", suffix=".bin")),
    "radiate": RealSource("radiate", real_radiate, _under("radiate", suffix=".csv")),
    # the full keyframe, the 40-point keyframe and a 100-point sweep (--include-sweeps)
    "nuscenes": RealSource(
        "nuscenes",
        real_nuscenes,
        lambda: [
            f"nuscenes/{NUSC_FULL_SAMPLE}",
            f"nuscenes-tiny/{NUSC_TINY_SAMPLE}",
            f"nuscenes-tiny/{NUSC_TINY_SWEEP}",
        ],
        {"version": "v1.0-mini", "include_sweeps": True},
    ),
    "nuscenes-scene0001": RealSource(
        "nuscenes",
        real_nuscenes_scene0001,
        _under("nuscenes-scene0001", suffix="points.bin"),
        {"version": "v1.0-trainval"},
    ),
    "nuscenes-kitti": RealSource(
        "nuscenes-kitti", real_nuscenes_kitti, _under("nuscenes-kittifmt", suffix=".bin")
    ),
    "nuscenes-scans": RealSource(
        "nuscenes-scans",
        real_nuscenes_scans,
        lambda: [
            f"nuscenes/{NUSC_FULL_SAMPLE}",
            NUSC_LONE_SWEEP,
            *(f"nuscenes-scene0001/{d}/points.bin" for d in NUSC_SCANS_SCENE0001),
        ],
    ),
}


# Real files no tree can hold, with the reason (none since loose scans have a reader).
NOT_BUILDABLE: dict[str, str] = {}


def real_scan_files() -> list[str]:
    """Every point-cloud file under ../shared/data (relative paths): KITTI-layout scans,
    nuScenes .pcd.bin and points.bin, RADIATE CSV."""
    found = []
    for path in SHARED_DATA.rglob("*"):
        rel = path.relative_to(SHARED_DATA).as_posix()
        if path.suffix == ".csv" or rel.endswith((".pcd.bin", "/points.bin")):
            found.append(rel)
        elif path.suffix == ".bin" and path.parent.name == "velodyne":
            found.append(rel)
    return sorted(found)
