"""A sensor transfer's window, read for the worker: neighbouring scans, their poses and their
surfels (`lads.stages.sensor`, docs/transfer.md §3); and the poses around a frame for a
stage that takes the vehicle's motion from them (`run_track_stage`).

The worker owns this I/O; the stage stays a pure function of the scans it is handed. Each
worker process keeps the surfels of the scans it read last, so a build that walks a
sequence prepares every scan about once, not once per window that holds it. Surfels are a
deterministic function of a scan, so the cache never changes an output byte.
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from lads.errors import CorruptItemError, InputDataError
from lads.files import sha256_file
from lads.frame import Frame, Item
from lads.readers.base import Reader
from lads.transfer.window import window_of

F64 = npt.NDArray[np.float64]
# Scans a worker keeps beyond one window's (each 10-20 MB of surfels for an HDL-64E scan).
WINDOW_SPARE = 4


class WindowStage(Protocol):
    """A stage that transfers a frame from its window (`lads.stages.sensor.SensorStage`)."""

    name: str
    neighbours: int

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame: ...

    def prepare(self, frame: Frame) -> Any: ...

    def call_window(
        self,
        frame: Frame,
        parts: list[Any],
        poses: list[F64],
        centre: int,
        window: tuple[str, ...],
        rng: np.random.Generator,
    ) -> Frame: ...


class _Prepared:
    """`prepare` of the scans read last, by (stage identity, item id), oldest dropped first."""

    def __init__(self) -> None:
        self.entries: OrderedDict[tuple[Any, ...], Any] = OrderedDict()

    def get(self, key: tuple[Any, ...], make: Any, size: int) -> Any:
        if key in self.entries:
            self.entries.move_to_end(key)
            return self.entries[key]
        value = make()
        self.entries[key] = value
        while len(self.entries) > size:
            self.entries.popitem(last=False)
        return value


_PREPARED = _Prepared()


@functools.lru_cache(maxsize=4)
def _items(reader: Any, stamp: tuple[str, int]) -> tuple[Item, ...]:
    """Every item of the reader's tree (a window may reach beyond the items being built);
    `reader` is a Reader, typed Any as an lru_cache key (a Protocol is not Hashable);
    `stamp` (`_stamp`) makes a worker reused by a later build list a changed tree again."""
    return tuple(reader.items())


@functools.lru_cache(maxsize=4)
def _placed(reader: Any, stamp: tuple[str, int]) -> tuple[Item, ...]:
    """The tree's items that have a place in time (`scan_position`); a scan whose name is
    not a number fails as its own item and is no other frame's neighbour."""
    out = []
    for item in _items(reader, stamp):
        try:
            reader.scan_position(item)
        except CorruptItemError:
            continue
        out.append(item)
    return tuple(out)


@functools.lru_cache(maxsize=64)
def _sequence_poses(reader: Any, sequence: str, stamp: tuple[str, int]) -> dict[str, F64]:
    """Pose of every scan of one sequence of the tree, read once per worker."""
    position = reader.scan_position
    items = [it for it in _placed(reader, stamp) if position(it)[0] == sequence]
    return reader.sensor_poses(items)  # type: ignore[no-any-return]


def run_window_stage(
    stage: WindowStage,
    stage_key: str,
    reader: Reader,
    item: Item,
    frame: Frame,
    rng: np.random.Generator,
) -> Frame:
    """`frame` (the item as read) through `stage` with its window of the reader's tree.

    Raises:
        InputDataError: the reader has no poses or scan order (the message says which
            readers do), or a pose is missing (the reader's own error says where).
    """
    if stage.neighbours == 0:
        return stage(frame, rng)  # a window of the frame's own scan
    if not (hasattr(reader, "scan_position") and hasattr(reader, "sensor_poses")):
        raise InputDataError(
            f"{item.relpath}: the {stage.name} stage needs the sequence's poses, which "
            f"source {type(reader).__name__} does not read; use a source with poses "
            "(semantickitti, nuscenes, nuscenes-kitti) or neighbours: 0 (each frame alone)."
        )
    keyed: Any = reader  # readers are hashable objects; the Reader protocol does not say so
    stamp = _stamp(reader, item)
    keyed.scan_position(item)  # a scan without a place in time fails here, alone
    window, centre = window_of(_placed(keyed, stamp), item, stage.neighbours, keyed.scan_position)
    if len(window) == 1:
        return stage(frame, rng)  # no neighbour in the tree: the frame's own pose cancels
    try:
        poses = _sequence_poses(keyed, keyed.scan_position(item)[0], stamp)
    except CorruptItemError as exc:
        raise CorruptItemError(
            f"{exc} (Without poses, `--neighbours 0` transfers each frame from its own scan.)"
        ) from exc
    # One window and a few more: a worker handed every k-th frame (k jobs) needs k new scans
    # per frame, and the window holds most of the next frame's.
    size = stage.neighbours + 1 + WINDOW_SPARE
    parts = [
        _prepare(stage, (stage_key, *stamp), it, frame if it == item else None, size, reader)
        for it in window
    ]
    return stage.call_window(
        frame,
        parts,
        [poses[it.relpath] for it in window],
        centre,
        tuple(it.relpath for it in window),
        rng,
    )


def run_track_stage(
    stage: Any, reader: Reader, item: Item, frame: Frame, rng: np.random.Generator
) -> Frame:
    """`frame` through a stage that needs its scan's poses and times (`stage.call_track`:
    motion distortion from poses), with the reader's `pose_track` of the item.

    Raises:
        InputDataError: the reader has no poses (the message says which readers do).
        CorruptItemError: a pose file is missing or malformed (the reader's own message).
    """
    track = getattr(reader, "pose_track", None)
    if track is None:
        raise InputDataError(
            f"{item.relpath}: the {stage.name} stage takes the vehicle's motion from the "
            f"sequence's poses, which source {type(reader).__name__} does not read; use a "
            "source with poses (semantickitti, nuscenes, nuscenes-kitti) or give the motion "
            "(speed_m_s or a severity)."
        )
    return stage.call_track(frame, track(item), rng)  # type: ignore[no-any-return]


def _stamp(reader: Reader, item: Item) -> tuple[str, int]:
    """(tree root, modification time of the folder of the item's scan): a worker's caches of
    the tree's items, poses and surfels hold for one state of that folder (a scan added or
    replaced between two builds changes it)."""
    folder = (Path(reader.root) / item.relpath).parent
    try:
        return str(Path(reader.root).resolve()), folder.stat().st_mtime_ns
    except OSError:
        return str(reader.root), -1


def _prepare(
    stage: WindowStage,
    key: tuple[Any, ...],
    item: Item,
    frame: Frame | None,
    size: int,
    reader: Reader,
) -> Any:
    def make() -> Any:
        return stage.prepare(frame if frame is not None else reader.read(item))

    return _PREPARED.get((*key, item.item_id), make, size)


def window_source_rows(
    reader: Reader, item: Item, window: tuple[str, ...], tracked: bool = False
) -> list[dict[str, Any]]:
    """{path, bytes, sha256} of every file the output drew on besides `item`'s own: the
    files of the window's other scans and, when the stages used poses (a window of more
    than the frame, or `tracked`: a stage took the motion from them), the reader's pose
    files. For the manifest row: a changed neighbour or pose changes the output, and
    verify and resume see it."""
    paths: list[str] = []
    if len(window) > 1:
        keyed: Any = reader  # as in run_window_stage
        by_path = {it.relpath: it for it in _items(keyed, _stamp(reader, item))}
        for rel in window:
            paths += by_path[rel].source_relpaths() if rel != item.relpath else []
    if (len(window) > 1 or tracked) and hasattr(reader, "pose_relpaths"):
        paths += reader.pose_relpaths(item)
    rows = []
    for path in paths:
        full = Path(reader.root) / path
        stat = full.stat()
        digest = _digest(str(full), stat.st_size, stat.st_mtime_ns)
        rows.append({"path": path, "bytes": stat.st_size, "sha256": digest})
    return rows


@functools.lru_cache(maxsize=512)
def _digest(path: str, size: int, mtime_ns: int) -> str:
    """sha256 of a file, once per (path, size, mtime) in a worker."""
    return sha256_file(Path(path))
