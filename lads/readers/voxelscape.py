"""Voxelscape: simulated HDL-64E-like scans with three per-point label files.

Layout (docs/formats.md §3.2), relative to the reader root (the folder that holds the `SS`
sequence folders, `VoxelScape/dataset/` in the devkit README):

    SS/velodyne/xyz_iom_NNNNNN.bin            headerless little-endian float32, N x 4:
                                              x, y, z in m, intensity continuous in [0, 1)
    SS/kitti_labels/xyz_iom_NNNNNN.label      uint32, N: Voxelscape's kitti-label ids; the same
                                              numbers as SemanticKITTI but 14 of them name other
                                              classes (docs/formats.md §3.3): never map them with
                                              SemanticKITTI's label map
    SS/orig_labels/xyz_iom_NNNNNN.label       int32, N: the 32 raw Voxelscape classes
    SS/orig_labels/xyz_iom_NNNNNN_subl.label  int32, N: fine sub-labels
    SS/bboxs/xyz_iom_NNNNNN.pkl               boxes; not per point, copied byte for byte
    SS/labels/xyz_iom_NNNNNN.label            int32, N: the devkit loaders' labels folder
                                              (`sequences/SS/labels/`, read as int32 there);
                                              carried point by point as role "devkit_labels"

Each label kind is optional per sequence (decided by what the sequence's folders hold); when
present, every scan needs its file and every file holds exactly N records. There is no
calib, poses or times file.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from lads.errors import DatasetNotFoundError
from lads.frame import Frame, Item
from lads.readers.base import (
    EncodedFile,
    check_finite,
    encode_labels,
    encode_scan_and_labels,
    entries_matching,
    normalize_sequences,
    read_labels,
    read_records,
    select_sequences,
)

_SUBL = "_subl.label"
SCAN_PREFIX = "xyz_iom_"  # every Voxelscape file name: xyz_iom_NNNNNN
EXTRA_DTYPES = {
    "orig_labels": np.dtype(np.int32),
    "orig_sublabels": np.dtype(np.int32),
    "devkit_labels": np.dtype(np.int32),
}


def _sequence_names(folder: Path) -> list[str]:
    if not folder.is_dir():
        return []
    return [d.name for d in folder.iterdir() if (d / "velodyne").is_dir()]


class VoxelscapeReader:
    """Reader and encoder of Voxelscape trees.

    Args:
        root: the folder that holds the `SS` sequence folders; a folder holding
            `dataset/SS/` is accepted too, and `root` then becomes that `dataset/` folder.
        sequences: sequence names ("00", 7, ...) to restrict to; None for all.

    Frames: columns ("x", "y", "z", "intensity"); points (N, 4) float32; labels (N,) uint32
    (kitti_labels) or None; extra_labels "orig_labels" and "orig_sublabels", (N,) int32 each,
    when the sequence has them.
    """

    name = "voxelscape"
    sensor = "voxelscape64"
    particle_label = 1  # kitti_labels 1 "outlier" keeps its SemanticKITTI meaning
    label_set = "voxelscape"
    columns: tuple[str, ...] = ("x", "y", "z", "intensity")
    record_fixed_by: str | None = None  # headerless .bin: loaders are told the column count
    label_dtype = np.dtype(np.uint32)

    def __init__(self, root: str | Path, *, sequences: Iterable[str | int] | None = None):
        given = Path(root)
        if not _sequence_names(given) and _sequence_names(given / "dataset"):
            given = given / "dataset"
        self.root = given
        self.sequences = normalize_sequences(sequences)

    def __repr__(self) -> str:
        return f"VoxelscapeReader({str(self.root)!r}, sequences={self.sequences!r})"

    def _expected(self) -> str:
        return (
            f"the Voxelscape layout SS/velodyne/xyz_iom_NNNNNN.bin (+ kitti_labels/, "
            f"orig_labels/) under {self.root}; pass the folder that holds the SS folders"
        )

    def _selected(self) -> list[str]:
        if not self.root.is_dir():
            raise DatasetNotFoundError(f"{self.root}: no such folder; expected {self._expected()}.")
        found = _sequence_names(self.root)
        return select_sequences(found, self.sequences, self.root, self._expected())

    def items(self) -> list[Item]:
        """Every scan of the selected sequences, sorted by relpath."""
        items = []
        for seq in self._selected():
            kitti = (self.root / seq / "kitti_labels").is_dir()
            orig_dir = self.root / seq / "orig_labels"
            names = [p.name for p in orig_dir.glob("*.label")] if orig_dir.is_dir() else []
            has_orig = any(not n.endswith(_SUBL) for n in names)
            has_subl = any(n.endswith(_SUBL) for n in names)
            # The devkit loaders' tree: never drop its labels, carry them with each point.
            devkit = (self.root / seq / "labels").is_dir()
            roles = {"kitti": kitti, "orig": has_orig, "subl": has_subl, "devkit": devkit}
            for scan in entries_matching(self.root / seq / "velodyne", ".bin"):
                items.append(self._item(seq, scan.name, **roles))
        if not items:
            raise DatasetNotFoundError(
                f"{self.root}: no scans found (sequences {self.sequences or 'all'}); "
                f"expected {self._expected()}."
            )
        return sorted(items, key=lambda it: it.relpath)

    def _item(
        self, seq: str, scan_name: str, *, kitti: bool, orig: bool, subl: bool, devkit: bool
    ) -> Item:
        """The item of scan file `scan_name` of sequence `seq`, with the label files whose
        kinds are true: kitti_labels, orig_labels, orig_labels `_subl`, devkit labels."""
        stem = Path(scan_name).stem
        extras = []
        if orig:
            extras.append(("orig_labels", f"{seq}/orig_labels/{stem}.label"))
        if subl:
            extras.append(("orig_sublabels", f"{seq}/orig_labels/{stem}{_SUBL}"))
        if devkit:
            extras.append(("devkit_labels", f"{seq}/labels/{stem}.label"))
        label = f"{seq}/kitti_labels/{stem}.label" if kitti else None
        return Item(self.name, f"{seq}/velodyne/{scan_name}", label, tuple(extras))

    def new_item(self, sequence: str, number: int) -> Item:
        """The item scan `number` of `sequence` has in a new tree of this layout with all
        three label kinds, as `items()` lists it once the files exist: scan
        `SS/velodyne/xyz_iom_NNNNNN.bin`, label `SS/kitti_labels/xyz_iom_NNNNNN.label`,
        extras ("orig_labels", `SS/orig_labels/xyz_iom_NNNNNN.label`) and
        ("orig_sublabels", `SS/orig_labels/xyz_iom_NNNNNN_subl.label`); number zero-padded
        to 6 digits. No devkit `labels/` file.

        Not part of the `Reader` protocol: for writers of new trees (`lads synth`), which
        build a `Frame` of this item (labels uint32, extra_labels int32) and write the files
        `encode` returns.
        """
        scan_name = f"{SCAN_PREFIX}{number:06d}.bin"
        return self._item(sequence, scan_name, kitti=True, orig=True, subl=True, devkit=False)

    def copied_files(self) -> list[str]:
        """The per-frame box files (`SS/bboxs/**`) of the selected sequences, if any."""
        out: list[str] = []
        for seq in self._selected():
            boxes = self.root / seq / "bboxs"
            if boxes.is_dir():
                out.extend(p.relative_to(self.root).as_posix() for p in boxes.rglob("*"))
        return sorted(rel for rel in out if not (self.root / rel).is_dir())

    def read(self, item: Item) -> Frame:
        """Scan (N, C) float32 of the C `columns` (4 in Voxelscape's own record), kitti labels
        (N,) uint32, extras (N,) int32 each."""
        path = self.root / item.relpath
        c = len(self.columns)
        points = read_records(path, np.float32, c, f"Voxelscape scan (N x {c} float32)")
        check_finite(points, path, self.columns)
        n = points.shape[0]
        labels = None
        if item.label_relpath is not None:
            labels = read_labels(
                self.root / item.label_relpath,
                self.label_dtype,
                n,
                "Voxelscape kitti_labels (uint32 per point)",
                path,
                why="this sequence has a kitti_labels/ folder",
            )
        extras = {
            role: read_labels(
                self.root / rel,
                EXTRA_DTYPES[role],
                n,
                f"Voxelscape {role} (int32 per point)",
                path,
                why=f"this sequence's {rel.split('/')[-2]}/ folder holds such files",
            )
            for role, rel in item.extra_relpaths
        }
        return Frame.from_source(item, self.sensor, self.columns, points, labels, extras)

    def encode(self, frame: Frame) -> list[EncodedFile]:
        """Scan, kitti_labels (uint32) and orig_labels / _subl (int32), as the item has them."""
        item = frame.item
        n = frame.points.shape[0]
        files = encode_scan_and_labels(frame, len(self.columns), self.label_dtype)
        for role, rel in item.extra_relpaths:
            files.append(
                encode_labels(
                    frame.extra_labels.get(role), EXTRA_DTYPES[role], n, rel, role, item.item_id
                )
            )
        return files
