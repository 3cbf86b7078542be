"""Dataset readers: one module per on-disk format, all following `lads.readers.base.Reader`.

`READERS` maps each reader name (the `--source` of `lads build`, the `dataset` of an
`Item`) to its class; `get_reader` builds one with its options, and with the point record
a lads tree's run.json says its scans hold.
"""

from __future__ import annotations

import copy
import inspect
import json
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, cast

from lads.errors import ConfigError, InputDataError, LadsError, PointFormatError
from lads.frame import Frame
from lads.physics.materials import LABEL_SETS
from lads.readers.base import EncodedFile, Reader
from lads.readers.nuscenes import NuScenesReader
from lads.readers.nuscenes_kitti import NuScenesKittiReader
from lads.readers.nuscenes_scans import NuScenesScansReader
from lads.readers.radiate import RadiateReader
from lads.readers.semantickitti import SemanticKittiReader
from lads.readers.voxelscape import VoxelscapeReader
from lads.readers.wads import WadsReader

READERS: dict[str, type] = {
    "semantickitti": SemanticKittiReader,
    "nuscenes": NuScenesReader,
    "nuscenes-kitti": NuScenesKittiReader,
    "nuscenes-scans": NuScenesScansReader,
    "voxelscape": VoxelscapeReader,
    "wads": WadsReader,
    "radiate": RadiateReader,
}


def label_set_for(dataset: str) -> str | None:
    """The material label set of a dataset's labels (a reader's `label_set`; other names,
    such as "synth", when they are label sets themselves), None for unlabelled datasets."""
    reader = READERS.get(dataset)
    if reader is not None:
        return cast("type[Reader]", reader).label_set
    return dataset if dataset in LABEL_SETS else None


def reader_class(name: str) -> type[Reader]:
    """The reader class `name`, for its class-level facts (sensor, label_set, columns).

    Raises:
        ConfigError: unknown reader name (the message lists the valid ones).
    """
    if name not in READERS:
        raise ConfigError(
            f"unknown dataset reader {name!r}; valid names: {', '.join(sorted(READERS))}."
        )
    return cast("type[Reader]", READERS[name])


def get_reader(name: str, root: str | Path, **options: Any) -> Reader:
    """Build the reader `name` for the tree at `root` with its keyword `options`.

    Every reader also takes `sensor`: the profile of the tree's scans when it is not the
    dataset's own (a tree lads transferred to another sensor, whose run.json names it).
    A lads tree whose run.json records scans of other columns than the format's own (a
    transfer written in the target's native record) is read with those columns
    (`with_columns`).

    Raises:
        ConfigError: unknown reader name (the message lists the valid ones), an option the
            reader does not take (the message lists the ones it does), an unknown sensor,
            or a tree recorded in another sensor's point record than `sensor` names.
    """
    sensor = options.pop("sensor", None)
    reader = _build(name, root, options)
    if sensor is not None:
        from lads.sensors.profile import load_profile

        try:
            load_profile(sensor)
        except LadsError as exc:
            raise ConfigError(f"reader {name!r}: sensor {sensor!r}: {exc}") from None
        reader.sensor = str(sensor)  # the instance's profile shadows the dataset's
    return _as_recorded(reader)


def _build(name: str, root: str | Path, options: dict[str, Any]) -> Reader:
    try:
        cls = READERS[name]
    except KeyError:
        raise ConfigError(
            f"unknown dataset reader {name!r}; valid names: {', '.join(sorted(READERS))}."
        ) from None
    signature = inspect.signature(cls)
    try:
        signature.bind(root, **options)
    except TypeError as exc:
        accepted = [p for p in signature.parameters if p != "root"]
        raise ConfigError(
            f"reader {name!r}: {exc}; its options are {accepted or 'none'}."
        ) from None
    return cls(root, **options)


def with_columns(reader: Reader, columns: Sequence[str]) -> Reader:
    """`reader` for scan files of `columns` (float32 each, in file order) instead of its
    format's own, in the same layout: a lads tree written in another sensor's native record
    (`--point-format target`). `reader` itself when the columns are its own, else a copy.

    Raises:
        PointFormatError: the format's own tooling reads every scan with its own columns
            (`record_fixed_by`), so files of other columns would be misread.
    """
    columns = tuple(str(c) for c in columns)
    if columns == tuple(reader.columns):
        return reader
    if reader.record_fixed_by:
        raise PointFormatError(
            f"{reader.root}: {reader.name} scans of {len(columns)} columns "
            f"({', '.join(columns)}) cannot be read or written: {reader.record_fixed_by}. "
            f"Keep the {reader.name} record ({', '.join(reader.columns)}), --point-format source."
        )
    out = copy.copy(reader)
    out.columns = columns  # the instance's record shadows the format's
    return out


def _as_recorded(reader: Reader) -> Reader:
    """`reader` with the scan columns its tree's run.json records (`point_columns`), when
    the tree is a lads build whose scans hold another record than the format's own.

    Raises:
        ConfigError: the record is malformed, or is another sensor's than the reader's.
    """
    from lads.built_tree import RUN_JSON

    path = Path(reader.root) / RUN_JSON
    try:
        run = json.loads(path.read_text())
    except (OSError, ValueError):
        return reader  # no run.json, or a dataset's own file of that name: the format's record
    if not (isinstance(run, dict) and "lads_version" in run):
        return reader
    columns = run.get("point_columns")
    sensor = run.get("sensor")
    if isinstance(sensor, str) and sensor != reader.sensor:
        # A tree lads built for another sensor (a transfer, in either record): its points
        # are that sensor's, intensity encoding included.
        record = f" ({', '.join(map(str, columns))})" if isinstance(columns, list) else ""
        raise ConfigError(
            f"{path}: the scans hold the {sensor} sensor's points{record}, but the "
            f"{reader.name} reader was told sensor {reader.sensor}; pass --sensor {sensor} "
            "(reader option sensor) to read this tree."
        )
    if columns is None or columns == list(reader.columns):
        return reader
    if not (isinstance(columns, list) and columns and all(isinstance(c, str) for c in columns)):
        raise ConfigError(
            f"{path}: point_columns is {columns!r}; expected the list of column names lads "
            "wrote. The file was edited: restore it from the tree's SHA256SUMS or rebuild."
        )
    return with_columns(reader, columns)


__all__ = ["READERS", "EncodedFile", "Reader", "get_reader", "label_set_for", "with_columns"]


def read_scan(name: str, root: str | Path, path: str | Path) -> Frame:
    """The item of reader `name` (rooted at `root`) whose scan file is `path`, read.

    For tools that take a scan file rather than a tree (calibration, figures): the reader
    decides the layout, the label file and the parsing.

    Raises:
        InputDataError: `path` is not a scan of that tree.
        ConfigError: unknown reader name.
    """
    return read_scans(name, root, [path])[0]


def read_scans(name: str, root: str | Path, paths: Iterable[str | Path]) -> list[Frame]:
    """`read_scan` for several scan files of one tree, listing its items once."""
    reader = get_reader(name, root)
    base = os.path.abspath(reader.root)
    items = {item.relpath: item for item in reader.items()}
    frames = []
    for path in paths:
        rel = Path(os.path.relpath(os.path.abspath(path), base)).as_posix()
        if rel not in items:
            raise InputDataError(
                f"{path}: not a scan of the {name} tree at {root}; pass a scan file inside a "
                f"{name} tree laid out as the reader expects."
            )
        frames.append(reader.read(items[rel]))
    return frames
