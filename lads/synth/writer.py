"""Write a synthetic sequence as a SemanticKITTI, Voxelscape or nuScenes-lidarseg dataset tree
(docs/formats.md §1-§3).

The per-scan files go through the dataset's reader (lads/readers/): its `new_item` names a
new scan's files and its `encode` turns a `Frame` of the synthetic points and labels into
their bytes, so the file names and encodings are stated only there. What is synthesis stays
here: which values the frames hold (Voxelscape: continuous reflectivity capped at
`_VOXELSCAPE_MAX` and three label codes per part; nuScenes: LIDAR_TOP axes, the hdl32e
intensity bytes, the ring column and lidarseg indices), SemanticKITTI's calib, poses and
times (written under the reader's file names), and the nuScenes tokens, tables and map of a
one-log, one-scene database (lads/synth/nuscenes.py). Every file is written to `<name>.tmp`
and renamed into place.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from lads.errors import BuildError, ConfigError
from lads.files import atomic_write
from lads.frame import Frame, Item
from lads.readers.base import EncodedFile
from lads.readers.nuscenes import NuScenesReader
from lads.readers.semantickitti import (
    CALIB_FILE,
    POSES_FILE,
    TIMES_FILE,
    SemanticKittiReader,
)
from lads.readers.voxelscape import VoxelscapeReader
from lads.sensors.profile import SensorProfile, load_profile
from lads.synth import nuscenes as nusc
from lads.synth.frames import SynthFrame, synth_frames
from lads.synth.voxelscape import voxelscape_ids

LAYOUTS = ("semantickitti", "nuscenes", "voxelscape")
# Sensor profile when the caller gives none: the one each dataset was recorded with.
DEFAULT_SENSOR = {"semantickitti": "hdl64e", "nuscenes": "hdl32e", "voxelscape": "hdl64e"}

# KITTI odometry sequence 00 calibration (data_odometry_calib, sequences/00/calib.txt): P0-P3
# are the rectified camera projections, Tr maps velodyne -> left grey camera (cam0).
KITTI_CALIB: dict[str, tuple[float, ...]] = {
    "P0": (718.856, 0.0, 607.1928, 0.0, 0.0, 718.856, 185.2157, 0.0, 0.0, 0.0, 1.0, 0.0),
    "P1": (718.856, 0.0, 607.1928, -386.1448, 0.0, 718.856, 185.2157, 0.0, 0.0, 0.0, 1.0, 0.0),
    "P2": (718.856, 0.0, 607.1928, 45.38225, 0.0, 718.856, 185.2157, -0.1130887, 0.0, 0.0,
           1.0, 0.003779761),
    "P3": (718.856, 0.0, 607.1928, -337.2877, 0.0, 718.856, 185.2157, 2.369057, 0.0, 0.0, 1.0,
           0.004915215),
    "Tr": (4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02,
           -7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02,
           9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01),
}  # fmt: skip
# The top of the voxelscape64 profile's [0, 0.9999] encoding, so lads reads its own trees.
_VOXELSCAPE_MAX = np.float32(0.9999)


@dataclass(frozen=True, slots=True)
class SynthSummary:
    """What write_synthetic_dataset wrote.

    Attributes:
        out_root: the tree's root directory.
        layout: "semantickitti", "nuscenes" or "voxelscape".
        sensor: profile name.
        frames: number of frames.
        points_per_frame: points in each frame, in frame order.
        files: every file written, as POSIX paths relative to out_root, sorted.
    """

    out_root: Path
    layout: str
    sensor: str
    frames: int
    points_per_frame: tuple[int, ...]
    files: tuple[str, ...]


def write_synthetic_dataset(
    out_root: Path,
    *,
    sensor: str | None = None,
    frames: int = 20,
    layout: str = "semantickitti",
    sequence: str = "00",
    seed: int = 0,
    progress: bool = False,
    azimuth_bins: int | None = None,
) -> SynthSummary:
    """Ray-cast `frames` sweeps of the seeded street and write them as one sequence.

    Args:
        out_root: root of the tree (created if missing).
        sensor: profile name or YAML path (lads.sensors.profile.load_profile); None picks
            the layout's own sensor (DEFAULT_SENSOR: hdl64e, or hdl32e for nuscenes). Any
            profile works with any layout (nuscenes: ring = channel index). A named sensor's
            scans hold its own intensity encoding (build them with --sensor SENSOR); without
            one, Voxelscape's hold its continuous reflectivity (read as voxelscape64's).
        frames: number of 10 Hz frames, >= 1 (nuscenes: each one a keyframe, NUSC_KEYFRAME_US
            apart).
        layout: "semantickitti", "nuscenes" or "voxelscape".
        sequence: sequence folder name, digits only (e.g. "00"); for nuscenes the scene is
            named `scene-<sequence as 4 digits>`.
        seed: non-negative; the same arguments give byte-identical trees.
        progress: show a tqdm bar (on stderr, only when it is a terminal).
        azimuth_bins: beams per channel; default the profile's range_image_width.

    Returns:
        SynthSummary of the written tree.

    Raises:
        ConfigError: unknown layout, frames < 1, bad sequence or seed, an unknown sensor
            (SensorProfileError), or a sequence folder holding frame files this run would
            not overwrite.
        BuildError: a file cannot be written.
    """
    _check_arguments(layout, frames, sequence, seed)
    profile = load_profile(DEFAULT_SENSOR[layout] if sensor is None else sensor)
    out_root = Path(out_root)
    plan_of = _LAYOUT_PLANS[layout]
    if layout == "voxelscape" and sensor is not None:
        plan_of = functools.partial(_voxelscape, continuous=False)  # the sensor's own encoding
    plan = plan_of(out_root, sequence, seed, profile, frames)
    _refuse_stale_files(_expected_files(out_root, plan))
    frame_iter = synth_frames(profile, frames=frames, seed=seed, azimuth_bins=azimuth_bins)
    bar = tqdm(frame_iter, total=frames, unit="frame", disable=None if progress else True)
    written, points, poses, times = _write_frames(out_root, plan, bar)
    written += plan.finish(poses, times)
    return SynthSummary(
        out_root=out_root,
        layout=layout,
        sensor=profile.name,
        frames=frames,
        points_per_frame=tuple(points),
        files=tuple(sorted(p.relative_to(out_root).as_posix() for p in written)),
    )


def _check_arguments(layout: str, frames: int, sequence: str, seed: int) -> None:
    """Raise ConfigError for the first of `write_synthetic_dataset`'s arguments out of range."""
    if layout not in LAYOUTS:
        raise ConfigError(f"layout '{layout}' is unknown; use one of: {', '.join(LAYOUTS)}.")
    if not isinstance(frames, int) or frames < 1:
        raise ConfigError(f"frames={frames!r}; give an integer >= 1 (e.g. 20).")
    if not re.fullmatch(r"\d+", sequence):
        raise ConfigError(f"sequence '{sequence}' must be digits only, e.g. '00'.")
    if seed < 0:
        raise ConfigError(f"seed={seed}; give a non-negative integer.")


def _atomic_write(path: Path, payload: bytes) -> Path:
    try:
        atomic_write(path, payload)
    except OSError as exc:
        raise BuildError(
            f"{path}: cannot write ({exc}); give an --out directory that is writable and has "
            "free space."
        ) from exc
    return path


# (item, synthetic frame) -> the Frame the layout's reader encodes into the item's files.
_FrameOf = Callable[[Item, SynthFrame], Frame]
# ((4, 4) sensor -> world poses, times in s, of every frame) -> the side files written.
_Finisher = Callable[[list[npt.NDArray[np.float64]], list[float]], list[Path]]


@dataclass(frozen=True, slots=True)
class _LayoutPlan:
    """How one layout turns the synthetic frames into a tree.

    Attributes:
        encode: the layout's reader's `encode`: a frame's files (relpath, bytes).
        items: the item of each frame, in frame order (the reader's `new_item`).
        frame_of: the Frame of an item's synthetic frame, in the reader's columns and dtypes.
        side_dirs: folders (absolute) of the side files and the names `finish` writes there.
        finish: writes the side files once every frame is written.
    """

    encode: Callable[[Frame], list[EncodedFile]]
    items: list[Item]
    frame_of: _FrameOf
    side_dirs: dict[Path, set[str]]
    finish: _Finisher


def _expected_files(out_root: Path, plan: _LayoutPlan) -> dict[Path, set[str]]:
    """Every folder this run writes frame or side files into, with the names it writes."""
    expected: dict[Path, set[str]] = {}
    for item in plan.items:
        for rel in item.source_relpaths():
            path = out_root / rel
            expected.setdefault(path.parent, set()).add(path.name)
    for folder, names in plan.side_dirs.items():
        expected.setdefault(folder, set()).update(names)
    return expected


def _refuse_stale_files(expected: dict[Path, set[str]]) -> None:
    """Raise ConfigError when a folder of `expected` holds a file this run would not write."""
    for folder, allowed in expected.items():
        if not folder.is_dir():
            continue
        stale = sorted(p.name for p in folder.iterdir() if p.name not in allowed)
        if stale:
            raise ConfigError(
                f"{folder} already holds {len(stale)} file(s) this run would not overwrite "
                f"(e.g. {stale[0]}), which would leave an inconsistent sequence; write to an "
                "empty --out directory or delete that sequence first."
            )


def _write_frames(
    out_root: Path, plan: _LayoutPlan, frames: Iterable[SynthFrame]
) -> tuple[list[Path], list[int], list[npt.NDArray[np.float64]], list[float]]:
    """Files written, points per frame, (4, 4) poses and times (s) of the frames, in order.

    Each frame's files are the ones its reader encodes, written at out_root / relpath.
    """
    written: list[Path] = []
    points: list[int] = []
    poses, times = [], []
    for item, frame in zip(plan.items, frames, strict=True):
        for encoded in plan.encode(plan.frame_of(item, frame)):
            written.append(_atomic_write(out_root / encoded.relpath, encoded.payload))
        points.append(int(frame.xyz.shape[0]))
        poses.append(frame.pose)
        times.append(frame.time_s)
    return written, points, poses, times


def _xyz_intensity(
    xyz: npt.NDArray[np.float32], intensity: npt.NDArray[np.float32]
) -> npt.NDArray[np.float32]:
    """(N, 4) float32 points x, y, z (m), intensity."""
    return np.column_stack([xyz, intensity]).astype(np.float32)


def _semantickitti(
    out_root: Path, sequence: str, seed: int, profile: SensorProfile, frames: int
) -> _LayoutPlan:
    """SemanticKITTI: the reader's items and encoding, plus the sequence's calib (KITTI
    sequence 00), cam0 poses and `%e` times under the reader's side-file names."""
    reader = SemanticKittiReader(out_root)

    def frame_of(item: Item, f: SynthFrame) -> Frame:
        points = _xyz_intensity(f.xyz, f.intensity)
        return Frame.from_source(item, profile.name, reader.columns, points, f.labels)

    def finish(poses: list[npt.NDArray[np.float64]], times: list[float]) -> list[Path]:
        calib = "".join(f"{k}: {_floats(v, '%.12e')}\n" for k, v in KITTI_CALIB.items())
        contents = {
            CALIB_FILE: calib,
            POSES_FILE: _kitti_poses(poses),
            TIMES_FILE: "".join(f"{t:e}\n" for t in times),
        }
        return [
            _atomic_write(out_root / reader.sequence_file(sequence, name), text.encode())
            for name, text in contents.items()
        ]

    items = [reader.new_item(sequence, k) for k in range(frames)]
    return _LayoutPlan(reader.encode, items, frame_of, {}, finish)


def _voxelscape(
    out_root: Path,
    sequence: str,
    seed: int,
    profile: SensorProfile,
    frames: int,
    continuous: bool = True,
) -> _LayoutPlan:
    """Voxelscape: points with the continuous reflectivity as intensity (`continuous`, the
    format's own) or the profile's encoded intensity, kitti_labels and the orig / sub-label
    codes of each generator part (voxelscape_ids.yaml); no side files."""
    reader, ids = VoxelscapeReader(out_root), voxelscape_ids()

    def frame_of(item: Item, f: SynthFrame) -> Frame:
        # Continuous physical intensity rho * cos(incidence) * texture, clipped below 1.
        # kitti_labels keep the instance ids in the high 16 bits, as SemanticKITTI does
        # (Voxelscape leaves those bits undocumented; readers mask with 0xFFFF).
        intensity = (
            np.clip(f.reflectivity, 0.0, _VOXELSCAPE_MAX).astype(np.float32)
            if continuous
            else f.intensity
        )
        kitti = (f.labels >> 16 << 16) | ids.kitti_of_part[f.part]
        extras: dict[str, npt.NDArray[np.generic]] = {
            "orig_labels": ids.orig_of_part[f.part],
            "orig_sublabels": ids.subl_of_part[f.part],
        }
        points = _xyz_intensity(f.xyz, intensity)
        return Frame.from_source(item, profile.name, reader.columns, points, kitti, extras)

    items = [reader.new_item(sequence, k) for k in range(frames)]
    return _LayoutPlan(reader.encode, items, frame_of, {}, lambda poses, times: [])


# nuScenes layout. nuScenes keyframes are 2 Hz (LiDAR sweeps 20 Hz); every synthetic frame
# (10 Hz, 1 m apart) becomes a keyframe with timestamps NUSC_KEYFRAME_US apart, so the
# timestamps say 2 m/s while the poses move 10 m/s. No sweeps are written.
NUSC_T0_US = 1_530_000_000_000_000  # 2018-06-26 08:00:00 UTC
NUSC_KEYFRAME_US = 500_000
NUSC_LOG = "n000-2018-06-26-08-00-00+0000"  # the real naming pattern; vehicle n000 = synthetic


def _nuscenes(
    out_root: Path, sequence: str, seed: int, profile: SensorProfile, frames: int
) -> _LayoutPlan:
    """nuScenes-lidarseg: one keyframe per frame (NUSC_KEYFRAME_US apart, tokens salted by
    seed and sequence), points in LIDAR_TOP axes with ring, lidarseg labels, then the tables
    and map of a one-log, one-scene database."""
    version, classes = nusc.VERSION, nusc.lidarseg_classes()
    reader = NuScenesReader(out_root, version=version)
    scene = _nuscenes_scene(sequence, seed, profile)

    def frame_of(item: Item, f: SynthFrame) -> Frame:
        points = nusc.nuscenes_points(f.xyz, f.intensity, f.ring)
        labels = classes.labels(f.labels)
        return Frame.from_source(item, profile.name, reader.columns, points, labels)

    def finish(poses: list[npt.NDArray[np.float64]], times: list[float]) -> list[Path]:
        records = []
        for item, pose in zip(items, poses, strict=True):
            translation, rotation = nusc.ego_pose_of(pose)
            sd_token = dict(item.meta)["sample_data_token"]
            records.append(
                nusc.NuscSampleData(
                    sd_token,
                    item.relpath,
                    True,
                    item.label_relpath,
                    ego_translation=translation,
                    ego_rotation=rotation,
                )
            )
        tables = nusc.nuscenes_tables(version, records, scene)
        return [_atomic_write(out_root / rel, payload) for rel, payload in tables.items()]

    items = []
    for k in range(frames):
        filename = reader.keyframe_filename(NUSC_LOG, NUSC_T0_US + NUSC_KEYFRAME_US * k)
        items.append(reader.new_item(filename, nusc.token(scene.salt + filename), version))
    tables = {Path(p).name for p in nusc.table_files(version, lidarseg=True)}
    map_png = out_root / nusc.map_relpath(version, scene)
    side_dirs = {out_root / version: tables, map_png.parent: {map_png.name}}
    return _LayoutPlan(reader.encode, items, frame_of, side_dirs, finish)


def _nuscenes_scene(sequence: str, seed: int, profile: SensorProfile) -> nusc.NuscScene:
    """The one log and scene of a synthetic nuScenes tree; `salt` seeds its tokens."""
    return nusc.NuscScene(
        logfile=NUSC_LOG,
        vehicle=NUSC_LOG[:4],
        date_captured=NUSC_LOG[5:15],
        location="lads-synthetic-street",
        name=f"scene-{int(sequence):04d}",
        description=f"lads synth street, seed {seed}, sensor {profile.name}",
        sensor_translation=nusc.SENSOR_TRANSLATION,
        sensor_rotation=nusc.SENSOR_ROTATION,
        salt=f"lads-synth:{seed}:{sequence}:",
    )


_LAYOUT_PLANS: dict[str, Callable[[Path, str, int, SensorProfile, int], _LayoutPlan]] = {
    "semantickitti": _semantickitti,
    "nuscenes": _nuscenes,
    "voxelscape": _voxelscape,
}


def _floats(values: npt.ArrayLike, fmt: str) -> str:
    return " ".join(fmt % v for v in np.asarray(values, dtype=np.float64).ravel())


def kitti_poses_cam0(poses: list[npt.NDArray[np.float64]]) -> npt.NDArray[np.float64]:
    """(F, 4, 4) cam0 poses relative to the first frame: Tr @ inv(T_0) @ T_k @ inv(Tr).

    Args:
        poses: F (4, 4) sensor -> world poses (SynthFrame.pose).
    """
    tr = np.eye(4)
    tr[:3, :] = np.reshape(KITTI_CALIB["Tr"], (3, 4))
    first_inv, tr_inv = np.linalg.inv(poses[0]), np.linalg.inv(tr)
    cam = np.stack([tr @ first_inv @ p @ tr_inv for p in poses])
    cam[0] = np.eye(4)  # exactly, not up to rounding
    return cam


def _kitti_poses(poses: list[npt.NDArray[np.float64]]) -> str:
    return "".join(f"{_floats(p[:3, :], '%e')}\n" for p in kitti_poses_cam0(poses))
