"""Write a synthetic sequence as a SemanticKITTI, Voxelscape or nuScenes-lidarseg dataset tree
(docs/formats.md §1-§3).

SemanticKITTI: `sequences/SS/{velodyne/NNNNNN.bin, labels/NNNNNN.label, calib.txt, poses.txt,
times.txt}`. Voxelscape: `SS/{velodyne, kitti_labels, orig_labels}/xyz_iom_NNNNNN.*` plus
`orig_labels/xyz_iom_NNNNNN_subl.label`, no calib, poses or times. nuScenes: a v1.0-mini
dataroot, `samples/LIDAR_TOP/<log>__LIDAR_TOP__<us>.pcd.bin`, `lidarseg/v1.0-mini/
<token>_lidarseg.bin`, `v1.0-mini/*.json` and `maps/<token>.png`, one log and one scene whose
samples are the frames (lads/synth/nuscenes.py). Every file is written to `<name>.tmp` and
renamed into place.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from lads.errors import BuildError, ConfigError
from lads.files import atomic_write
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
            profile works with any layout (nuscenes: ring = channel index, intensity
            re-encoded as nuScenes bytes).
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
    write_frame, frame_dirs, finish = _LAYOUT_WRITERS[layout](out_root, sequence, seed, profile)
    names = [f"{k:06d}" for k in range(frames)]
    _refuse_stale_files(out_root, frame_dirs, names)
    frame_iter = synth_frames(profile, frames=frames, seed=seed, azimuth_bins=azimuth_bins)
    bar = tqdm(frame_iter, total=frames, unit="frame", disable=None if progress else True)
    written, points, poses, times = _write_frames(write_frame, names, bar)
    written += finish(poses, times)
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


def _scan_bytes(xyz: npt.NDArray[np.float32], intensity: npt.NDArray[np.float32]) -> bytes:
    return np.column_stack([xyz, intensity]).astype("<f4").tobytes()


def _refuse_stale_files(
    out_root: Path, frame_dirs: dict[Path, Callable[[str], set[str]]], names: list[str]
) -> None:
    for folder, expected in frame_dirs.items():
        if not folder.is_dir():
            continue
        allowed = set().union(*(expected(n) for n in names))
        stale = sorted(p.name for p in folder.iterdir() if p.name not in allowed)
        if stale:
            raise ConfigError(
                f"{folder} already holds {len(stale)} file(s) this run would not overwrite "
                f"(e.g. {stale[0]}), which would leave an inconsistent sequence; write to an "
                "empty --out directory or delete that sequence first."
            )


_FrameWriter = Callable[[str, SynthFrame], list[Path]]
_Finisher = Callable[[list[npt.NDArray[np.float64]], list[float]], list[Path]]


def _write_frames(
    write_frame: _FrameWriter, names: list[str], frames: Iterable[SynthFrame]
) -> tuple[list[Path], list[int], list[npt.NDArray[np.float64]], list[float]]:
    """Files written, points per frame, (4, 4) poses and times (s) of the frames, in order."""
    written: list[Path] = []
    points: list[int] = []
    poses, times = [], []
    for name, frame in zip(names, frames, strict=True):
        written += write_frame(name, frame)
        points.append(int(frame.xyz.shape[0]))
        poses.append(frame.pose)
        times.append(frame.time_s)
    return written, points, poses, times


def _semantickitti(
    out_root: Path, sequence: str, seed: int, profile: SensorProfile
) -> tuple[_FrameWriter, dict[Path, Callable[[str], set[str]]], _Finisher]:
    seq = out_root / "sequences" / sequence

    def write_frame(name: str, f: SynthFrame) -> list[Path]:
        return [
            _atomic_write(seq / "velodyne" / f"{name}.bin", _scan_bytes(f.xyz, f.intensity)),
            _atomic_write(seq / "labels" / f"{name}.label", f.labels.astype("<u4").tobytes()),
        ]

    def finish(poses: list[npt.NDArray[np.float64]], times: list[float]) -> list[Path]:
        calib = "".join(f"{k}: {_floats(v, '%.12e')}\n" for k, v in KITTI_CALIB.items())
        return [
            _atomic_write(seq / "calib.txt", calib.encode()),
            _atomic_write(seq / "poses.txt", _kitti_poses(poses).encode()),
            _atomic_write(seq / "times.txt", "".join(f"{t:e}\n" for t in times).encode()),
        ]

    dirs: dict[Path, Callable[[str], set[str]]] = {
        seq / "velodyne": lambda n: {f"{n}.bin"},
        seq / "labels": lambda n: {f"{n}.label"},
    }
    return write_frame, dirs, finish


def _voxelscape(
    out_root: Path, sequence: str, seed: int, profile: SensorProfile
) -> tuple[_FrameWriter, dict[Path, Callable[[str], set[str]]], _Finisher]:
    seq, ids = out_root / sequence, voxelscape_ids()

    def write_frame(name: str, f: SynthFrame) -> list[Path]:
        # Continuous physical intensity rho * cos(incidence) * texture, clipped below 1.
        # kitti_labels keep the instance ids in the high 16 bits, as SemanticKITTI does
        # (Voxelscape leaves those bits undocumented; readers mask with 0xFFFF).
        intensity = np.clip(f.reflectivity, 0.0, _VOXELSCAPE_MAX).astype(np.float32)
        kitti = (f.labels >> 16 << 16) | ids.kitti_of_part[f.part]
        stem = f"xyz_iom_{name}"
        return [
            _atomic_write(seq / "velodyne" / f"{stem}.bin", _scan_bytes(f.xyz, intensity)),
            _atomic_write(seq / "kitti_labels" / f"{stem}.label", kitti.astype("<u4").tobytes()),
            _atomic_write(
                seq / "orig_labels" / f"{stem}.label",
                ids.orig_of_part[f.part].astype("<i4").tobytes(),
            ),
            _atomic_write(
                seq / "orig_labels" / f"{stem}_subl.label",
                ids.subl_of_part[f.part].astype("<i4").tobytes(),
            ),
        ]

    dirs: dict[Path, Callable[[str], set[str]]] = {
        seq / "velodyne": lambda n: {f"xyz_iom_{n}.bin"},
        seq / "kitti_labels": lambda n: {f"xyz_iom_{n}.label"},
        seq / "orig_labels": lambda n: {f"xyz_iom_{n}.label", f"xyz_iom_{n}_subl.label"},
    }
    return write_frame, dirs, lambda poses, times: []


# nuScenes layout. nuScenes keyframes are 2 Hz (LiDAR sweeps 20 Hz); every synthetic frame
# (10 Hz, 1 m apart) becomes a keyframe with timestamps NUSC_KEYFRAME_US apart, so the
# timestamps say 2 m/s while the poses move 10 m/s. No sweeps are written.
NUSC_T0_US = 1_530_000_000_000_000  # 2018-06-26 08:00:00 UTC
NUSC_KEYFRAME_US = 500_000
NUSC_LOG = "n000-2018-06-26-08-00-00+0000"  # the real naming pattern; vehicle n000 = synthetic


def _nuscenes(
    out_root: Path, sequence: str, seed: int, profile: SensorProfile
) -> tuple[_FrameWriter, dict[Path, Callable[[str], set[str]]], _Finisher]:
    version, classes = nusc.VERSION, nusc.lidarseg_classes()
    scene = nusc.NuscScene(
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
    records: list[nusc.NuscSampleData] = []

    def scan_name(name: str) -> str:
        return f"{NUSC_LOG}__{nusc.CHANNEL}__{NUSC_T0_US + NUSC_KEYFRAME_US * int(name)}.pcd.bin"

    def label_name(name: str) -> str:
        return f"{nusc.token(scene.salt + scan_name(name))}_lidarseg.bin"

    def write_frame(name: str, f: SynthFrame) -> list[Path]:
        scan = f"samples/{nusc.CHANNEL}/{scan_name(name)}"
        labels = f"lidarseg/{version}/{label_name(name)}"
        translation, rotation = nusc.ego_pose_of(f.pose)
        records.append(
            nusc.NuscSampleData(
                nusc.token(scene.salt + scan_name(name)),
                scan,
                True,
                labels,
                ego_translation=translation,
                ego_rotation=rotation,
            )
        )
        payload = nusc.nuscenes_scan(f.xyz, f.intensity, f.reflectivity, f.ring, profile)
        return [
            _atomic_write(out_root / scan, payload),
            _atomic_write(out_root / labels, classes.labels(f.labels).tobytes()),
        ]

    def finish(poses: list[npt.NDArray[np.float64]], times: list[float]) -> list[Path]:
        tables = nusc.nuscenes_tables(version, records, scene)
        return [_atomic_write(out_root / rel, payload) for rel, payload in tables.items()]

    tables = {Path(p).name for p in nusc.table_files(version, lidarseg=True)}
    map_png = Path(nusc.map_relpath(version, scene))
    dirs: dict[Path, Callable[[str], set[str]]] = {
        out_root / "samples" / nusc.CHANNEL: lambda n: {scan_name(n)},
        out_root / "lidarseg" / version: lambda n: {label_name(n)},
        out_root / version: lambda n: tables,
        out_root / map_png.parent: lambda n: {map_png.name},
    }
    return write_frame, dirs, finish


_LAYOUT_WRITERS = {
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
