"""Loose nuScenes LIDAR_TOP scans without the devkit tables (docs/formats.md §4).

A lone keyframe, a sample folder copied out of a dataroot or a simulator's output often holds
the scans alone. Every scan file anywhere below the reader root is one item:

    **/*.pcd.bin      headerless little-endian float32, N x 5: x, y, z in m (LIDAR_TOP frame),
                      intensity 0-255, ring 0-31 (nuScenes' own scan files); unlabelled
    **/points.bin     the same records, with its lidarseg labels beside it in
    **/ground.bin     headerless uint8, N: the lidarseg class index (0-31) of each point

Points are never filtered (zero-range placeholders and ego-body returns stay, labels are
matched by index). Without the tables there are no poses, timestamps or calibration: what
needs them (the nuScenes reader's sweeps and tokens) is not available on such a tree.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lads.errors import DatasetNotFoundError
from lads.frame import Frame, Item
from lads.readers.base import EncodedFile, encode_scan_and_labels, read_scan_and_labels
from lads.readers.nuscenes import DEVKIT_RECORD

SCAN_SUFFIX = ".pcd.bin"
POINTS_NAME, LABELS_NAME = "points.bin", "ground.bin"


class NuScenesScansReader:
    """Reader and encoder of a folder of loose nuScenes LIDAR_TOP scans.

    Args:
        root: any folder; every `*.pcd.bin` and `points.bin` below it is a scan.

    Frames: columns ("x", "y", "z", "intensity", "ring"); points (N, 5) float32, intensity
    0-255; labels (N,) uint8 lidarseg class indices for a `points.bin` with a `ground.bin`.
    """

    name = "nuscenes-scans"
    sensor = "hdl32e"
    particle_label = 0  # lidarseg "noise"
    label_set = "nuscenes"
    columns: tuple[str, ...] = ("x", "y", "z", "intensity", "ring")
    record_fixed_by: str | None = DEVKIT_RECORD
    label_dtype = np.dtype(np.uint8)

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.root)!r})"

    def items(self) -> list[Item]:
        """Every scan file below the root, sorted by relpath."""
        if not self.root.is_dir():
            raise DatasetNotFoundError(f"{self.root}: no such folder; expected {_EXPECTED}.")
        items = []
        for folder, dirs, files in os.walk(self.root, followlinks=True):
            dirs.sort()
            here = Path(folder)
            for name in sorted(files):
                if not (name.endswith(SCAN_SUFFIX) or name == POINTS_NAME):
                    continue
                rel = (here / name).relative_to(self.root).as_posix()
                label = None
                if name == POINTS_NAME and (here / LABELS_NAME).is_file():
                    label = (here / LABELS_NAME).relative_to(self.root).as_posix()
                items.append(Item(self.name, rel, label))
        if not items:
            raise DatasetNotFoundError(f"{self.root}: no scans found; expected {_EXPECTED}.")
        return sorted(items, key=lambda it: it.relpath)

    def copied_files(self) -> list[str]:
        """None: a loose scan has no side files."""
        return []

    def read(self, item: Item) -> Frame:
        """Scan (N, 5) float32 and, when it has a `ground.bin`, labels (N,) uint8."""
        points, labels = read_scan_and_labels(
            self.root,
            item,
            self.columns,
            "nuScenes LIDAR_TOP scan (N x 5 float32)",
            self.label_dtype,
            "lidarseg labels (uint8 per point)",
            f"a {LABELS_NAME} lies beside the scan",
        )
        return Frame.from_source(item, self.sensor, self.columns, points, labels)

    def encode(self, frame: Frame) -> list[EncodedFile]:
        """The scan (M x 20 bytes) and, if the item has one, its label file (M bytes)."""
        return encode_scan_and_labels(frame, 5, self.label_dtype)


_EXPECTED = (
    f"nuScenes LIDAR_TOP scans anywhere below it: *{SCAN_SUFFIX} or {POINTS_NAME} files (N x 5 "
    f"float32: x, y, z, intensity, ring), labels in a {LABELS_NAME} (N uint8) beside a "
    f"{POINTS_NAME}"
)
