"""Sensor poses of a sequence, as the datasets store them (docs/formats.md §1.5, §4).

KITTI odometry and SemanticKITTI: `sequences/SS/poses.txt` holds one 3 x 4 row-major pose per
scan (line i for scan i), in the frame of the left grey camera of scan 0; `calib.txt`'s `Tr`
maps Velodyne coordinates into that camera. The Velodyne's pose of scan i is then
Tr^-1 P_i Tr. The KITTI-style nuScenes export stores the lidar -> global pose itself; the
nuScenes tables store it as ego_pose (ego -> global) times calibrated_sensor (lidar -> ego).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from lads.errors import CorruptItemError

F64 = npt.NDArray[np.float64]

# A pose's or calibration's 3 x 3 part must be a rotation: max |R^T R - I| up to this (text
# files round their entries at 1e-6 or finer; a broken file is off by order 1), det R > 0.
RIGID_TOLERANCE = 1e-2


def _check_rigid(transforms: F64, path: Path, what: str, line_of: str) -> None:
    """Raise CorruptItemError naming the first (4, 4) of `transforms` (K, 4, 4) whose
    rotation part is not a rotation (`line_of`: how to say where it is, {k} its index)."""
    rot = transforms[:, :3, :3]
    gram = np.einsum("kji,kjl->kil", rot, rot)
    off = np.abs(gram - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = np.flatnonzero((off > RIGID_TOLERANCE) | ~(det > 0.0))
    if bad.size:
        k = int(bad[0])
        raise CorruptItemError(
            f"{path}: {what}, {line_of.format(k=k + 1)}: not a rigid transform (its 3 x 3 "
            f"part R has max |R^T R - I| = {off[k]:.3g} and det R = {det[k]:.3g}); expected "
            "[R | t] with R a rotation. Replace the file with the dataset's own."
        )


def read_pose_lines(path: Path, what: str) -> F64:
    """(K, 4, 4) float64 poses from a text file of K lines of 12 numbers (3 x 4 row-major).

    Raises:
        CorruptItemError: the file is missing or unreadable, a line is not 12 numbers, or a
            pose is not a rigid transform (`RIGID_TOLERANCE`).
    """
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CorruptItemError(
            f"{path}: cannot read {what} ({exc.strerror or exc}); a sensor transfer and motion "
            "from poses need the sequence's poses: put them there (one 3 x 4 row-major pose "
            "per scan)."
        ) from exc
    rows = [line.split() for line in text.splitlines() if line.strip()]
    bad = [k for k, r in enumerate(rows) if len(r) != 12]
    if bad:
        raise CorruptItemError(
            f"{path}: line {bad[0] + 1} has {len(rows[bad[0]])} numbers; expected 12 per line "
            f"(a 3 x 4 row-major pose) in {what}."
        )
    try:
        values = np.array(rows, dtype=np.float64).reshape(-1, 3, 4)
    except ValueError as exc:
        raise CorruptItemError(f"{path}: {what} holds text that is not a number ({exc}).") from exc
    if not np.isfinite(values).all():
        raise CorruptItemError(f"{path}: {what} holds NaN or infinite values.")
    out = np.tile(np.eye(4), (len(values), 1, 1))
    out[:, :3, :] = values
    _check_rigid(out, path, what, "line {k}")
    return out


def kitti_velodyne_to_camera(calib: Path) -> F64:
    """(4, 4) `Tr` of a KITTI `calib.txt`: Velodyne -> left grey camera.

    Raises:
        CorruptItemError: no readable `Tr:` line of 12 numbers, or one that is not a rigid
            transform.
    """
    try:
        lines = calib.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise CorruptItemError(
            f"{calib}: cannot read the calibration ({exc.strerror or exc}); a sensor transfer "
            "or motion from poses of KITTI scans needs its Tr (Velodyne -> camera) to turn "
            "the camera poses into Velodyne poses."
        ) from exc
    for line in lines:
        key, _, rest = line.partition(":")
        if key.strip() == "Tr":
            nums = rest.split()
            if len(nums) == 12:
                tr = np.eye(4)
                try:
                    tr[:3, :] = np.array(nums, dtype=np.float64).reshape(3, 4)
                except ValueError as exc:
                    raise CorruptItemError(
                        f"{calib}: the 'Tr:' line holds text that is not a number ({exc})."
                    ) from exc
                if not np.isfinite(tr).all():
                    raise CorruptItemError(f"{calib}: the 'Tr:' line holds NaN or infinite values.")
                _check_rigid(tr[None], calib, "the calibration", "line 'Tr'")
                return tr
    raise CorruptItemError(
        f"{calib}: no 'Tr:' line of 12 numbers; some KITTI downloads ship a calib.txt without "
        "it: take calib.txt from the KITTI odometry calibration archive."
    )


class PoseTrack(NamedTuple):
    """A frame's scan and its neighbours in time, as a reader gives them for motion from
    poses (`lads.physics.ego_motion.from_poses`).

    Attributes:
        times_s: (K,) float64 s, increasing; K is 2 or 3 (before, own, after; one side is
            missing at a sequence's ends).
        poses: (K, 4, 4) float64 sensor -> world poses of the same scans.
        centre: index of the frame's own scan.
        where: the pose file or scene, for messages.
    """

    times_s: F64
    poses: F64
    centre: int
    where: str


def track_around(times_s: F64, poses: F64, k: int, where: str) -> PoseTrack:
    """Scan `k` and the scans just before and after it of a sequence's (times, poses).

    Raises:
        CorruptItemError: no pose or time for scan k.
    """
    if not 0 <= k < min(len(poses), len(times_s)):
        raise CorruptItemError(
            f"{where}: {len(poses)} poses and {len(times_s)} times, none for scan {k}; "
            "expected one line per scan of the sequence."
        )
    lo, hi = max(k - 1, 0), min(k + 1, len(poses) - 1, len(times_s) - 1)
    return PoseTrack(times_s[lo : hi + 1], poses[lo : hi + 1], k - lo, where)


@functools.lru_cache(maxsize=16)
def _read_once(kind: str, path: str, what: str, mtime_ns: int) -> F64:
    values = read_pose_lines(Path(path), what) if kind == "poses" else _read_times(Path(path))
    values.setflags(write=False)  # shared by every later caller in this process
    return values


def _cached(kind: str, path: Path, what: str) -> F64:
    """A pose or times file, read once per state of the file in a process (a build asks for
    one sequence's poses once per frame); the array is read-only."""
    try:
        mtime_ns = path.stat().st_mtime_ns
    except OSError:  # missing: the reader's own message
        return read_pose_lines(path, what) if kind == "poses" else _read_times(path)
    return _read_once(kind, str(path), what, mtime_ns)


def pose_lines(path: Path, what: str) -> F64:
    """`read_pose_lines`, cached per state of the file; a read-only (K, 4, 4) array."""
    return _cached("poses", path, what)


def read_times(path: Path) -> F64:
    """(K,) float64 s of a KITTI `times.txt`, cached per state of the file; read-only.

    Raises:
        CorruptItemError: unreadable, not numbers, or not increasing.
    """
    return _cached("times", path, "the scan times")


def _read_times(path: Path) -> F64:
    """(K,) float64 s of a KITTI `times.txt` (one number per scan).

    Raises:
        CorruptItemError: unreadable, not numbers, or not increasing.
    """
    try:
        text = path.read_text(encoding="utf-8")
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise CorruptItemError(
            f"{path}: cannot read the scan times ({exc}); expected one time in s per line."
        ) from exc
    if values.size > 1 and not (np.diff(values) > 0).all():
        raise CorruptItemError(f"{path}: scan times do not increase; expected one per scan.")
    return values
