"""The Reader protocol: what every dataset module under `lads/readers/` provides.

A reader knows one on-disk format in both directions: it lists a tree's items, reads an
item into a `Frame`, and encodes a frame back into the bytes of the same files. It never
writes: the runner owns I/O on the output side (atomic writes, hashing, manifests).
Readers must be cheap to construct and picklable, because every worker builds its own:
expensive work (e.g. walking the nuScenes tables) belongs in `items()` only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from lads.frame import Frame, Item


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
        root: the source root directory.
    """

    name: str
    sensor: str
    particle_label: int
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


def read_records(path: Path, dtype: np.dtype | type, columns: int, what: str) -> np.ndarray:
    """Read a headerless little-endian binary file of `columns` values per record.

    Returns (N, columns) (or (N,) when columns == 1) in `dtype`.
    Raises CorruptItemError when the file is unreadable or its size is not a whole number
    of records.
    """
    from lads.errors import CorruptItemError

    dt = np.dtype(dtype).newbyteorder("<")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CorruptItemError(
            f"{path}: cannot read {what} ({exc.strerror or exc}); check that the file exists "
            "and is readable."
        ) from exc
    record = dt.itemsize * columns
    if len(raw) % record:
        raise CorruptItemError(
            f"{path}: {len(raw)} bytes is not a whole number of {record}-byte records "
            f"({columns} x {dt.name}) for {what}; the file is truncated or not in this format. "
            "Re-extract it from the dataset archive."
        )
    values = np.frombuffer(raw, dtype=dt).astype(dt.newbyteorder("="), copy=False)
    return values if columns == 1 else values.reshape(-1, columns)
