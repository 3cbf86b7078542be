"""nuScenes keyframes exported to a KITTI-style layout (docs/formats.md §4): 4-column scans.

Some 4D segmentation and moving-object codebases (SegNet4D's `nuScenes_kitti` export, for
one) turn nuScenes-lidarseg into per-scene folders, relative to the reader root:

    <split>/<scene>/velodyne/NNNNNN.bin      headerless little-endian float32, N x 4: x, y, z
                                             in m (LIDAR_TOP frame), intensity 0-255. The
                                             ring column of the original .pcd.bin is dropped;
                                             N is unchanged (a multiple of 32)
    <split>/<scene>/sem_labels/NNNNNN.label  headerless uint8, N: the raw lidarseg class index
                                             (0-31, 31 = ego vehicle), as in nuScenes
    <split>/<scene>/poses.txt                one 3 x 4 lidar -> global pose per keyframe;
                                             copied byte for byte

NNNNNN is the keyframe's index in its scene. Points are never filtered: the export keeps
nuScenes' zero-range placeholders and ego-body returns, and labels are matched by index.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from lads.errors import CorruptItemError, DatasetNotFoundError
from lads.frame import Frame, Item
from lads.readers.base import (
    EncodedFile,
    encode_scan_and_labels,
    entries_matching,
    present,
    read_scan_and_labels,
    scan_number,
)
from lads.readers.poses import PoseTrack, pose_lines, track_around

SCANS, LABELS = "velodyne", "sem_labels"
# nuScenes annotates keyframes at 2 Hz; the export keeps no timestamps, so keyframe k is
# taken at k times this period (the real spacing varies by a few ms).
KEYFRAME_PERIOD_S = 0.5


class NuScenesKittiReader:
    """Reader and encoder of the KITTI-style nuScenes export.

    Args:
        root: the folder that holds the split folders (`train/`, `val/`, ...).
        sequences: scene folders to restrict to (the `--sequences` of `lads build`), as
            `<split>/<scene>` ("train/0002") or a bare scene name ("0002", any split); None
            for all.

    Frames: columns ("x", "y", "z", "intensity"); points (N, 4) float32, intensity 0-255;
    labels (N,) uint8 lidarseg class indices when the scene has `sem_labels/`.
    """

    name = "nuscenes-kitti"
    sensor = "hdl32e"
    particle_label = 0  # lidarseg "noise"
    label_set = "nuscenes"
    columns: tuple[str, ...] = ("x", "y", "z", "intensity")
    record_fixed_by: str | None = None  # headerless .bin: loaders are told the column count
    label_dtype = np.dtype(np.uint8)
    copied_names: tuple[str, ...] = ("poses.txt",)

    def __init__(self, root: str | Path, *, sequences: Iterable[str] | str | None = None):
        self.root = Path(root)
        if isinstance(sequences, str):
            sequences = [sequences]
        self.sequences = None if sequences is None else tuple(sorted({str(s) for s in sequences}))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.root)!r}, sequences={self.sequences!r})"

    def _expected(self) -> str:
        return (
            f"the layout <split>/<scene>/{SCANS}/NNNNNN.bin (+ {LABELS}/NNNNNN.label) under "
            f"{self.root}; pass the folder that holds the split folders"
        )

    def _selected(self) -> list[str]:
        if not self.root.is_dir():
            raise DatasetNotFoundError(f"{self.root}: no such folder; expected {self._expected()}.")
        found = sorted(
            f"{split.name}/{scene.name}"
            for split in self.root.iterdir()
            if split.is_dir()
            for scene in split.iterdir()
            if (scene / SCANS).is_dir()
        )
        if self.sequences is None:
            return found
        wanted = set(self.sequences)
        chosen = [s for s in found if s in wanted or s.split("/")[1] in wanted]
        matched = {w for w in wanted if any(c == w or c.split("/")[1] == w for c in chosen)}
        missing = sorted(wanted - matched)
        if missing:
            raise DatasetNotFoundError(
                f"{self.root}: scenes {missing} not found; expected {self._expected()}. "
                f"Available: {found or 'none'}."
            )
        return chosen

    def items(self) -> list[Item]:
        """Every scan of the selected scenes, sorted by relpath."""
        items = []
        for scene in self._selected():
            labelled = (self.root / scene / LABELS).is_dir()
            for scan in entries_matching(self.root / scene / SCANS, ".bin"):
                label = f"{scene}/{LABELS}/{scan.stem}.label" if labelled else None
                items.append(Item(self.name, f"{scene}/{SCANS}/{scan.name}", label))
        if not items:
            raise DatasetNotFoundError(f"{self.root}: no scans found; expected {self._expected()}.")
        return sorted(items, key=lambda it: it.relpath)

    def copied_files(self) -> list[str]:
        """poses.txt of every selected scene that has one."""
        return sorted(
            f"{scene}/{name}"
            for scene in self._selected()
            for name in self.copied_names
            if present(self.root / scene / name)
        )

    def read(self, item: Item) -> Frame:
        """Scan (N, C) float32 of the C `columns` (4 in the export's own record) and, when
        the scene is labelled, labels (N,) uint8."""
        points, labels = read_scan_and_labels(
            self.root,
            item,
            self.columns,
            f"nuScenes KITTI-style scan (N x {len(self.columns)} float32)",
            self.label_dtype,
            "lidarseg labels (uint8 per point)",
            f"this scene has a {LABELS}/ folder",
        )
        return Frame.from_source(item, self.sensor, self.columns, points, labels)

    def encode(self, frame: Frame) -> list[EncodedFile]:
        """The scan (M x 4 C bytes for the C `columns`: 16 in the export's own record) and, if
        the item has one, the label file (M bytes)."""
        return encode_scan_and_labels(frame, len(self.columns), self.label_dtype)

    def scan_position(self, item: Item) -> tuple[str, int]:
        """(scene, keyframe number) of an item: its place in time, for a sensor transfer's
        window (`lads.transfer.window`)."""
        return item.relpath.rsplit("/", 2)[0], scan_number(item.relpath)

    def pose_relpaths(self, item: Item) -> list[str]:
        """The file an item's pose comes from (its scene's poses.txt): a source of every
        output built from the poses."""
        return [f"{item.relpath.rsplit('/', 2)[0]}/poses.txt"]

    def sensor_poses(self, items: list[Item]) -> dict[str, npt.NDArray[np.float64]]:
        """(4, 4) lidar -> global pose of each item: line NNNNNN of its scene's poses.txt.

        Raises:
            CorruptItemError: poses.txt missing or malformed, or too few lines.
        """
        out: dict[str, npt.NDArray[np.float64]] = {}
        for scene in sorted({it.relpath.rsplit("/", 2)[0] for it in items}):
            path = self.root / scene / "poses.txt"
            poses = pose_lines(path, "the scene's lidar -> global poses")
            for it in items:
                if it.relpath.rsplit("/", 2)[0] != scene:
                    continue
                k = scan_number(it.relpath)
                if k >= len(poses):
                    raise CorruptItemError(
                        f"{path}: {len(poses)} poses, none for keyframe {k} ({it.relpath}); "
                        "expected one line per keyframe of the scene."
                    )
                out[it.relpath] = poses[k].copy()
        return out

    def pose_track(self, item: Item) -> PoseTrack:
        """The item's keyframe and the keyframes before and after it: lidar -> global poses
        from the scene's poses.txt, times k x KEYFRAME_PERIOD_S (the export has no times).

        Raises:
            CorruptItemError: poses.txt missing or malformed, or no pose for the keyframe.
        """
        path = self.root / item.relpath.rsplit("/", 2)[0] / "poses.txt"
        poses = pose_lines(path, "the scene's lidar -> global poses")
        times = np.arange(len(poses), dtype=np.float64) * KEYFRAME_PERIOD_S
        return track_around(times, poses, scan_number(item.relpath), str(path))
