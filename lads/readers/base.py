"""The Reader protocol: what every dataset module under `lads/readers/` provides.

A reader knows one on-disk format in both directions: it lists a tree's items, reads an
item into a `Frame`, and encodes a frame back into the bytes of the same files. It never
writes: the runner owns I/O on the output side (atomic writes, hashing, manifests).
Readers must be cheap to construct and picklable, because every worker builds its own:
expensive work (e.g. walking the nuScenes tables) belongs in `items()` only.
"""

from __future__ import annotations

import errno
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from lads.frame import RING_COLUMN, Frame, Item, not_lasers

# No automotive LiDAR measures beyond a few hundred metres: a coordinate beyond this is a
# corrupt file, not a return (and would blow up every range image built from it).
MAX_COORDINATE_M = 10_000.0
# Files macOS leaves beside each file on foreign file systems (AppleDouble metadata).
APPLEDOUBLE_PREFIX = "._"
# More lasers than any spinning LiDAR has (128 today): a ring value beyond is no laser.
MAX_LASERS = 256


@dataclass(frozen=True, slots=True)
class EncodedFile:
    """One output file of one item.

    Attributes:
        relpath: path relative to the output root (the source item's own relative path).
        role: "scan", "label" or an extra role such as "orig_labels".
        payload: the file's bytes.
        records: number of per-point records in the file (points or labels).
        record_bytes: bytes per record (16 for KITTI scans, 20 for nuScenes, 4 for uint32
            labels, 1 for lidarseg), so that size == records * record_bytes; 0 for text.
    """

    relpath: str
    role: str
    payload: bytes
    records: int
    record_bytes: int


class Reader(Protocol):
    """One dataset format. Construct with `Reader(root, **options)`.

    Attributes:
        name: the key in `lads.readers.READERS`, e.g. "semantickitti".
        sensor: the sensor profile name of this dataset's LiDAR, e.g. "hdl64e".
        particle_label: default label of particle (rain/snow/fog) returns in this dataset's
            label space (SemanticKITTI 1 "outlier", nuScenes 0 "noise").
        label_set: the material label set of its labels
            (`lads.physics.materials.LABEL_SETS`), None when the format has no labels;
            whether its labels carry instance bits is the label set's
            (`lads.physics.materials.has_instance_bits`).
        columns: names of the float32 columns of its scan files, in file order. A tree lads
            built in another sensor's record says so in its run.json, and `get_reader` gives
            that instance the recorded columns (`lads.readers.with_columns`).
        record_fixed_by: the tooling of this format that reads every scan file with its own
            column count, so a file of other columns would be misread (nuScenes' devkit
            reads each `.pcd.bin` as 5 float32 columns); None when the format's loaders are
            told the column count (headerless KITTI-style `.bin`), so that a tree may hold
            another sensor's native record (`--point-format target`, docs/transfer.md §3).
        root: the source root directory.

    Optional methods, outside the protocol (only some readers have them; callers check):
    `scan_position`, `sensor_poses` and `pose_track` (a scan's place in time and its
    poses, for sensor transfers and motion), and `new_item` (the item a new scan of the
    dataset would have, so that a writer of new trees, `lads synth`, gets its file names
    from the reader and its bytes from `encode`; SemanticKITTI, WADS, Voxelscape and
    nuScenes).
    """

    name: str
    sensor: str
    particle_label: int
    label_set: str | None
    columns: tuple[str, ...]
    record_fixed_by: str | None
    root: Path

    def items(self) -> list[Item]:
        """Every item of the tree, sorted by relpath. Raises DatasetNotFoundError if empty."""
        ...

    def copied_files(self) -> list[str]:
        """Relative paths of files copied byte for byte (calib, poses, times, tables, maps)."""
        ...

    def read(self, item: Item) -> Frame:
        """Read one item. Raises CorruptItemError naming the file on any inconsistency."""
        ...

    def encode(self, frame: Frame) -> list[EncodedFile]:
        """Encode a frame (N points, labels aligned) into the item's files, same relpaths."""
        ...


def entries_matching(folder: Path, suffix: str) -> list[Path]:
    """Every entry of `folder` whose name ends with `suffix`, whatever it is: a file, but
    also a directory, a dangling symbolic link or a link loop. Listing must not filter: a
    name that cannot be read becomes a failed item with its reason, never a silent gap."""
    try:
        with os.scandir(folder) as it:
            return sorted(Path(e.path) for e in it if e.name.endswith(suffix))
    except FileNotFoundError:
        return []


def scan_number(relpath: str) -> int:
    """The scan number a scan file is named by (`000123.bin` -> 123): its place in time.

    Raises:
        CorruptItemError: the name is not a number (a re-downloaded `000000 (1).bin`, a
            macOS `._000000.bin`).
    """
    from lads.errors import CorruptItemError

    stem = Path(relpath).name.split(".")[0]
    if not stem.isdigit():
        raise CorruptItemError(
            f"{relpath}: the scan's name is not its number (NNNNNN.bin), so it has no place "
            "in the sequence's time; variants that read poses (sensor-*, motion-recorded) "
            "need numbered scans: rename or remove the file."
        )
    return int(stem)


def present(path: Path) -> bool:
    """Whether a name exists at `path`, even as a dangling symbolic link (which then fails
    loudly when read, instead of being skipped)."""
    return os.path.lexists(path)


def unreadable_reason(path: Path, exc: OSError) -> str:
    """Why `path` cannot be read, in words a user can act on."""
    if path.is_symlink() and exc.errno == errno.ELOOP:
        return "a symbolic link loop"
    if path.is_symlink() and not path.exists():
        return f"a dangling symbolic link (to {os.readlink(path)})"
    if path.is_dir():
        return "a directory, not a file"
    return exc.strerror or str(exc)


def read_records(path: Path, dtype: np.dtype | type, columns: int, what: str) -> np.ndarray:
    """Read a headerless little-endian binary file of `columns` values per record.

    Returns (N, columns) (or (N,) when columns == 1) in `dtype`.
    Raises CorruptItemError when the file is unreadable or its size is not a whole number
    of records.
    """
    from lads.errors import CorruptItemError

    dt = np.dtype(dtype).newbyteorder("<")
    if path.name.startswith(APPLEDOUBLE_PREFIX):
        raise CorruptItemError(
            f"{path}: a macOS metadata file (AppleDouble '._' copy), not {what}; delete it "
            "(`find ROOT -name '._*' -delete`)."
        )
    try:
        # np.fromfile gives a writable buffer (bytes would give read-only arrays, which
        # numba compiles as a separate type) without a second copy of the file.
        raw = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise CorruptItemError(
            f"{path}: cannot read {what}: {unreadable_reason(path, exc)}. Check that the file "
            "exists and is readable, or restore it from the dataset archive."
        ) from exc
    record = dt.itemsize * columns
    if len(raw) % record:
        raise CorruptItemError(
            f"{path}: {len(raw)} bytes is not a whole number of {record}-byte records "
            f"({columns} x {dt.name}) for {what}; the file is truncated or not in this format. "
            "Re-extract it from the dataset archive."
        )
    values = raw.view(dt).astype(dt.newbyteorder("="), copy=False)
    return values if columns == 1 else values.reshape(-1, columns)


# Helpers shared by the readers. Read-side problems are CorruptItemError (the file is at
# fault); encode-side problems are InputDataError / InvalidPointsError (the frame is).


def check_finite(points: np.ndarray, path: Path, columns: tuple[str, ...]) -> None:
    """Raise CorruptItemError naming `path` when a scan is empty, or naming the first bad
    point and column on NaN/inf or on a coordinate beyond `MAX_COORDINATE_M`."""
    from lads.errors import CorruptItemError

    if points.shape[0] == 0:
        raise CorruptItemError(
            f"{path}: the scan holds no point (an empty file); a LiDAR sweep always has "
            "returns, so this is a truncated copy. Re-extract it from the dataset archive, or "
            "remove it from the source tree."
        )
    problem = unusable_values(points, columns)
    if problem is not None:
        raise CorruptItemError(
            f"{path}: {problem}. The file is corrupt: re-extract it from the dataset archive "
            "(lads never drops points, since labels are matched by index)."
        )
    if RING_COLUMN in columns:
        ring = points[:, columns.index(RING_COLUMN)]
        bad = not_lasers(ring, MAX_LASERS)
        if bad.any():
            raise CorruptItemError(
                f"{path}: {int(bad.sum())} of {ring.size} values of the '{RING_COLUMN}' column "
                f"are not laser numbers (e.g. {ring[bad][:3].tolist()}): the file holds another "
                f"record than {len(columns)} float32 columns ({', '.join(columns)}), such as "
                "a 4-column x, y, z, intensity file. Write it in this layout's record."
            )


def unusable_values(points: np.ndarray, columns: tuple[str, ...]) -> str | None:
    """What makes (N, C) `points` unusable, naming the first bad point and column: NaN or
    infinite values, or a coordinate beyond `MAX_COORDINATE_M`; None when there is none."""
    bad = ~np.isfinite(points)
    if bad.any():
        rows, cols = np.nonzero(bad)
        return (
            f"{rows.size} NaN or infinite values (first: point {rows[0]}, column "
            f"'{columns[cols[0]]}' = {points[rows[0], cols[0]]}); expected finite "
            f"{', '.join(columns)} values"
        )
    far = np.abs(points[:, :3]) > MAX_COORDINATE_M
    if far.any():
        rows, cols = np.nonzero(far)
        return (
            f"{rows.size} coordinates beyond {MAX_COORDINATE_M:g} m (first: point {rows[0]}, "
            f"column '{columns[cols[0]]}' = {points[rows[0], cols[0]]:g} m); no LiDAR "
            "measures that far"
        )
    return None


def read_labels(
    path: Path, dtype: np.dtype | type, n_points: int, what: str, scan: Path, why: str = ""
) -> np.ndarray:
    """Read (N,) per-point labels of `dtype` from `path`, checking it exists and N matches.

    `why` says why the file is expected (for the message when it is missing).
    Raises CorruptItemError naming the file when it is missing, unreadable, mis-sized or
    holds a different number of records than the scan `scan` has points.
    """
    from lads.errors import CorruptItemError

    dt = np.dtype(dtype)
    if not path.is_file():
        raise CorruptItemError(
            f"{path}: missing {what} for scan {scan}; expected {n_points} {dt.name} records "
            f"(one per point){' because ' + why if why else ''}. Restore the file from the "
            "dataset archive, or remove the scan from the source tree."
        )
    labels = read_records(path, dt, 1, what)
    if labels.shape[0] != n_points:
        raise CorruptItemError(
            f"{path}: {labels.shape[0]} {what} records but scan {scan} has {n_points} points; "
            f"expected one {dt.name} per point, in scan order. The two files do not belong "
            "together or one is truncated: re-extract both from the dataset archive."
        )
    return labels


def read_scan_and_labels(
    root: Path,
    item: Item,
    columns: tuple[str, ...],
    scan_what: str,
    label_dtype: np.dtype,
    label_what: str,
    why: str,
) -> tuple[np.ndarray, np.ndarray | None]:
    """An item's (N, len(columns)) float32 scan, finite, and its (N,) labels when the item
    has a label file (`why` it must exist, for the message when it does not).

    Raises:
        CorruptItemError: naming the scan or label file that is unreadable, mis-sized,
            non-finite or of another length.
    """
    path = root / item.relpath
    points = read_records(path, np.float32, len(columns), scan_what)
    check_finite(points, path, columns)
    labels = None
    if item.label_relpath is not None:
        labels = read_labels(
            root / item.label_relpath, label_dtype, points.shape[0], label_what, path, why=why
        )
    return points, labels


def encode_points(frame: Frame, n_columns: int, relpath: str) -> EncodedFile:
    """(M, n_columns) float32 points of `frame` -> headerless little-endian scan bytes."""
    from lads.errors import InvalidPointsError

    points = np.asarray(frame.points)
    if points.ndim != 2 or points.shape[1] != n_columns:
        raise InvalidPointsError(
            f"{frame.item.item_id}: points have shape {points.shape}, expected (M, {n_columns}) "
            f"for {relpath}; a stage changed the column layout ({frame.columns})."
        )
    if not np.isfinite(points).all():
        raise InvalidPointsError(
            f"{frame.item.item_id}: points hold NaN or inf; {relpath} would be unreadable. "
            "A stage produced non-finite values: fix the stage or its parameters."
        )
    payload = np.ascontiguousarray(points, dtype="<f4").tobytes()
    return EncodedFile(relpath, "scan", payload, points.shape[0], 4 * n_columns)


def encode_labels(
    values: np.ndarray | None,
    dtype: np.dtype | type,
    n_points: int,
    relpath: str,
    role: str,
    item_id: str,
) -> EncodedFile:
    """(M,) integer labels -> headerless little-endian `dtype` records, range-checked."""
    from lads.errors import InputDataError

    dt = np.dtype(dtype).newbyteorder("<")
    if values is None:
        raise InputDataError(
            f"{item_id}: the frame has no '{role}' array but the item has {relpath}; "
            "stages must carry every per-point array of the item through."
        )
    arr = np.asarray(values)
    if arr.shape != (n_points,):
        raise InputDataError(
            f"{item_id}: '{role}' has shape {arr.shape} but the frame has {n_points} points; "
            f"{relpath} needs exactly one {dt.name} per point."
        )
    if arr.dtype != dt.newbyteorder("="):
        if arr.dtype.kind not in "iub":
            raise InputDataError(
                f"{item_id}: '{role}' has dtype {arr.dtype}, expected integers for {relpath}."
            )
        info = np.iinfo(dt)
        if arr.size and (int(arr.min()) < info.min or int(arr.max()) > info.max):
            raise InputDataError(
                f"{item_id}: '{role}' values {int(arr.min())}..{int(arr.max())} do not fit "
                f"{dt.name} ({info.min}..{info.max}) in {relpath}."
            )
    payload = np.ascontiguousarray(arr, dtype=dt).tobytes()
    return EncodedFile(relpath, role, payload, n_points, dt.itemsize)


def normalize_sequences(sequences: object) -> tuple[str, ...] | None:
    """The `sequences` option as sorted unique names; ints and 1-digit names get 2 digits.

    None means every sequence. A single str or int is one sequence (not its characters).
    """
    if sequences is None:
        return None
    if isinstance(sequences, str | int):
        sequences = [sequences]
    names = set()
    for s in sequences:  # type: ignore[attr-defined]
        name = f"{s:02d}" if isinstance(s, int) else str(s)
        names.add(name.zfill(2) if name.isdigit() else name)
    return tuple(sorted(names))


def select_sequences(
    found: list[str], wanted: tuple[str, ...] | None, where: Path, layout: str
) -> list[str]:
    """Sequences of `found` selected by `wanted`; DatasetNotFoundError names missing ones."""
    from lads.errors import DatasetNotFoundError

    if wanted is None:
        return sorted(found)
    # A folder named by the number without the padding (`8` for 08) is that sequence.
    by_number = {int(f): f for f in found if f.isdigit()}
    wanted = tuple(
        by_number.get(int(w), w) if w.isdigit() and w not in found else w for w in wanted
    )
    missing = sorted(set(wanted) - set(found))
    if missing:
        raise DatasetNotFoundError(
            f"{where}: sequences {missing} not found; expected {layout}. Available: "
            f"{sorted(found) or 'none'}. Fix the sequences option or the root."
        )
    return sorted(wanted)


def encode_scan_and_labels(frame: Frame, columns: int, label_dtype: np.dtype) -> list[EncodedFile]:
    """The scan (M x columns float32) and, when the item has one, its label file (M labels).

    The common first part of every binary reader's `encode`; extra roles follow per reader.
    """
    item = frame.item
    files = [encode_points(frame, columns, item.relpath)]
    if item.label_relpath is not None:
        n = frame.points.shape[0]
        files.append(
            encode_labels(frame.labels, label_dtype, n, item.label_relpath, "label", item.item_id)
        )
    return files
