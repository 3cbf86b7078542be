"""SemanticKITTI: `sequences/SS/velodyne/NNNNNN.bin` scans with `labels/NNNNNN.label`.

Layout (docs/formats.md §1), relative to the reader root (the folder that holds `sequences/`):

    sequences/SS/velodyne/NNNNNN.bin     headerless little-endian float32, N x 4:
                                         x, y, z in m (Velodyne frame), remission in [0, 0.99]
    sequences/SS/labels/NNNNNN.label     headerless little-endian uint32, N: semantic id in
                                         the low 16 bits, instance id in the high 16 bits;
                                         sequences 00-10 only
    sequences/SS/{calib,poses,times}.txt copied byte for byte

A sequence with a `labels/` folder needs a `.label` for every scan (a missing one fails that
item at read time); a sequence without one (the test sequences 11-21) gives unlabelled items.
Points are never filtered or de-duplicated: labels are matched by index.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError, CorruptItemError, DatasetNotFoundError
from lads.frame import Frame, Item
from lads.readers.base import (
    EncodedFile,
    encode_scan_and_labels,
    entries_matching,
    normalize_sequences,
    present,
    read_scan_and_labels,
    scan_number,
    select_sequences,
)
from lads.readers.poses import (
    PoseTrack,
    kitti_velodyne_to_camera,
    pose_lines,
    read_times,
    track_around,
)
from lads.sensors.profile import load_profile

# The per-sequence side files: calibration, camera poses (one line per scan), scan times (s).
CALIB_FILE, POSES_FILE, TIMES_FILE = "calib.txt", "poses.txt", "times.txt"


class SemanticKittiReader:
    """Reader and encoder of the SemanticKITTI layout (also the base of `WadsReader`).

    Args:
        root: the folder that holds `sequences/`; a folder holding `dataset/sequences/`
            is accepted too, and `root` then becomes that `dataset/` folder (item relpaths
            always start with `sequences/`).
        sequences: sequence names ("00", 8, ...) to restrict to; None for all.

    Frames: columns ("x", "y", "z", "intensity"); points (N, 4) float32, xyz in m, intensity
    the stored remission; labels (N,) uint32 raw SemanticKITTI ids (instance << 16 | sem).
    """

    name = "semantickitti"
    sensor = "hdl64e"
    particle_label = 1  # "outlier"
    label_set: str | None = "semantickitti"
    columns: tuple[str, ...] = ("x", "y", "z", "intensity")
    record_fixed_by: str | None = None  # headerless .bin: loaders are told the column count
    label_dtype = np.dtype(np.uint32)
    copied_names: tuple[str, ...] = (CALIB_FILE, POSES_FILE, TIMES_FILE)
    scan_what = "SemanticKITTI scan (N x 4 float32: x, y, z, remission)"
    label_what = "SemanticKITTI labels (uint32 per point)"

    def __init__(self, root: str | Path, *, sequences: Iterable[str | int] | None = None):
        given = Path(root)
        if not (given / "sequences").is_dir() and (given / "dataset" / "sequences").is_dir():
            given = given / "dataset"
        self.root = given
        self.sequences = normalize_sequences(sequences)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.root)!r}, sequences={self.sequences!r})"

    def _expected(self) -> str:
        return (
            f"the {self.name} layout sequences/SS/velodyne/NNNNNN.bin (+ labels/NNNNNN.label) "
            f"under {self.root}; pass the folder that holds sequences/"
        )

    def _selected(self) -> list[str]:
        seq_root = self.root / "sequences"
        if not seq_root.is_dir():
            raise DatasetNotFoundError(f"{seq_root}: no such folder; expected {self._expected()}.")
        found = [d.name for d in seq_root.iterdir() if (d / "velodyne").is_dir()]
        return select_sequences(found, self.sequences, seq_root, self._expected())

    def items(self) -> list[Item]:
        """Every scan of the selected sequences, sorted by relpath."""
        items = []
        for seq in self._selected():
            labelled = (self.root / "sequences" / seq / "labels").is_dir()
            for scan in entries_matching(self.root / "sequences" / seq / "velodyne", ".bin"):
                items.append(self._item(seq, scan.name, labelled=labelled))
        if not items:
            raise DatasetNotFoundError(
                f"{self.root}: no scans found (sequences {self.sequences or 'all'}); "
                f"expected {self._expected()}."
            )
        return sorted(items, key=lambda it: it.relpath)

    def _item(self, sequence: str, scan_name: str, *, labelled: bool) -> Item:
        """The item of the scan file `scan_name` (`NNNNNN.bin`) of `sequence`."""
        base = f"sequences/{sequence}"
        label = f"{base}/labels/{Path(scan_name).stem}.label" if labelled else None
        return Item(self.name, f"{base}/velodyne/{scan_name}", label)

    def new_item(self, sequence: str, number: int) -> Item:
        """The item scan `number` of `sequence` has in a new labelled tree of this layout:
        `sequences/SS/velodyne/NNNNNN.bin` with `sequences/SS/labels/NNNNNN.label` (number
        zero-padded to 6 digits), as `items()` lists it once the files exist.

        Not part of the `Reader` protocol: for writers of new trees (`lads synth`), which
        build a `Frame` of this item and write the files `encode` returns.
        """
        return self._item(sequence, f"{number:06d}.bin", labelled=True)

    def sequence_file(self, sequence: str, name: str) -> str:
        """Relative path of the side file `name` (one of `copied_names`: calib.txt,
        poses.txt, times.txt) of `sequence`, e.g. `sequences/00/poses.txt`.

        Raises:
            ConfigError: `name` is not one of `copied_names`.
        """
        if name not in self.copied_names:
            raise ConfigError(
                f"{name!r} is not a {self.name} sequence file; expected one of "
                f"{', '.join(self.copied_names)}."
            )
        return f"sequences/{sequence}/{name}"

    def copied_files(self) -> list[str]:
        """calib.txt, poses.txt and times.txt of every selected sequence that has them."""
        out = []
        for seq in self._selected():
            for name in self.copied_names:
                rel = self.sequence_file(seq, name)
                if present(self.root / rel):
                    out.append(rel)
        return sorted(out)

    def read(self, item: Item) -> Frame:
        """Scan (N, C) float32 of the C `columns` (4 in SemanticKITTI's own record) and, when
        the item has them, labels (N,) uint32."""
        points, labels = read_scan_and_labels(
            self.root,
            item,
            self.columns,
            self._scan_what(),
            self.label_dtype,
            self.label_what,
            "this sequence has a labels/ folder",
        )
        return Frame.from_source(item, self.sensor, self.columns, points, labels)

    def _scan_what(self) -> str:
        """What read errors call a scan file: the format's own, or a lads tree's record."""
        if self.columns == type(self).columns:
            return self.scan_what
        names = ", ".join(self.columns)
        return f"{self.name} scan of a lads tree (N x {len(self.columns)} float32: {names})"

    def encode(self, frame: Frame) -> list[EncodedFile]:
        """The scan (M x 4 C bytes for the C `columns`: 16 in SemanticKITTI's own record) and,
        if the item has one, the label file (M x 4 bytes)."""
        return encode_scan_and_labels(frame, len(self.columns), self.label_dtype)

    def scan_position(self, item: Item) -> tuple[str, int]:
        """(sequence, scan number) of an item: its place in time, for a sensor transfer's
        window (`lads.transfer.window`)."""
        return item.relpath.split("/")[1], scan_number(item.relpath)

    def pose_relpaths(self, item: Item) -> list[str]:
        """The files an item's pose and time come from (poses.txt, calib.txt's Tr and, when
        present, times.txt): sources of every output built from the poses."""
        seq = item.relpath.split("/")[1]
        rels = [self.sequence_file(seq, POSES_FILE), self.sequence_file(seq, CALIB_FILE)]
        times = self.sequence_file(seq, TIMES_FILE)
        return rels + [times] if present(self.root / times) else rels

    def sensor_poses(self, items: list[Item]) -> dict[str, npt.NDArray[np.float64]]:
        """(4, 4) Velodyne -> world pose of each item, from its sequence's poses.txt (line i
        for scan i, camera frame) and calib.txt's Tr: Tr^-1 P_i Tr.

        Raises:
            CorruptItemError: poses.txt or calib.txt missing or malformed, or a scan number
                beyond the last pose.
        """
        out: dict[str, npt.NDArray[np.float64]] = {}
        for seq in sorted({it.relpath.split("/")[1] for it in items}):
            base = self.root / "sequences" / seq
            _require_pose_files(base)
            poses = pose_lines(base / POSES_FILE, "the sequence's camera poses")
            tr = kitti_velodyne_to_camera(base / CALIB_FILE)
            tr_inv = np.linalg.inv(tr)
            for it in items:
                if it.relpath.split("/")[1] != seq:
                    continue
                k = scan_number(it.relpath)
                if k >= len(poses):
                    raise CorruptItemError(
                        f"{base / POSES_FILE}: {len(poses)} poses, none for scan {k} "
                        f"({it.relpath}); expected one line per scan of the sequence."
                    )
                out[it.relpath] = tr_inv @ poses[k] @ tr
        return out

    def pose_track(self, item: Item) -> PoseTrack:
        """The item's scan and the scans before and after it: Velodyne poses (as
        `sensor_poses`) and times from times.txt, or, without times.txt, the scan number
        times the sensor's sweep period (KITTI records one scan per revolution).

        Raises:
            CorruptItemError: poses.txt, calib.txt or times.txt missing or malformed, or no
                pose for the scan.
        """
        base = self.root / "sequences" / item.relpath.split("/")[1]
        _require_pose_files(base)
        poses = pose_lines(base / POSES_FILE, "the sequence's camera poses")
        tr = kitti_velodyne_to_camera(base / CALIB_FILE)
        if (base / TIMES_FILE).is_file():
            times = read_times(base / TIMES_FILE)
        else:
            period = load_profile(self.sensor).sweep_period_s
            if period is None:
                raise CorruptItemError(
                    f"{base / TIMES_FILE}: missing, and sensor profile {self.sensor} has no "
                    "sweep_period_s to time the scans by; put the sequence's times.txt there."
                )
            times = np.arange(len(poses), dtype=np.float64) * period
        track = track_around(times, poses, scan_number(item.relpath), str(base / POSES_FILE))
        velodyne = np.linalg.inv(tr) @ track.poses @ tr
        return track._replace(poses=velodyne)


def _require_pose_files(base: Path) -> None:
    """CorruptItemError naming both poses.txt and calib.txt when both are missing (one
    missing file is named by the reading that needs it)."""
    missing = [name for name in (POSES_FILE, CALIB_FILE) if not present(base / name)]
    if len(missing) == 2:
        raise CorruptItemError(
            f"{base}: no {POSES_FILE} and no {CALIB_FILE}; poses need both (the camera poses, "
            "one 3 x 4 row-major line per scan, and calib.txt's Tr from the KITTI odometry "
            "calibration archive): put them there."
        )
