"""Open a simulated and a real dataset tree of one sensor and read their scans for diagnosis.

`open_trees` checks that the two roots hold scans of the same source and sensor (and, when
paired, the same relative paths); `TreePair.read_scan` gives one scan as a `Scan`: points at
zero range removed, every remaining point keeping its row number in the file, labels reduced
to class ids. The beam table is built from these (`lads.diagnose.data.beams`), which also drops
the points nearer than the sensor's minimum range (`lads.diagnose.data.minrange`).

nuScenes roots are read with the devkit tables when they hold a `v1.0-*` folder; otherwise
with the `nuscenes-scans` reader: every `*.pcd.bin` (or `points.bin`, labelled by a
`ground.bin` beside it) under the root is a loose LIDAR_TOP scan, which is what a lone
keyframe or a simulator's output usually looks like.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from lads.diagnose.data.table import SensorInfo
from lads.errors import (
    ConfigError,
    CorruptItemError,
    DatasetNotFoundError,
    DiagnoseError,
    IntensityEncodingError,
)
from lads.frame import Frame, Item, not_lasers
from lads.physics.materials import class_ids
from lads.physics.projection import MIN_RANGE_M
from lads.readers import Reader, get_reader
from lads.sensors.profile import SensorProfile, load_profile

SOURCES: tuple[str, ...] = ("semantickitti", "nuscenes", "wads")
Tree = Literal["sim", "real"]
# Sensors that report range-compensated, calibrated reflectivity (HDL-32E v2 firmware in
# nuScenes); HDL-64E remission (KITTI) and the WADS sensor report raw intensity.
_CALIBRATED_PROFILES = frozenset({"hdl32e"})
_EXAMPLES = 3


@dataclass(frozen=True, slots=True)
class Scan:
    """One scan, zero-range points removed.

    Attributes:
        relpath: the scan's path relative to its tree root.
        xyz: (N, 3) float64 coordinates in m, sensor frame.
        intensity: (N,) float32 intensity in the stored units of the sensor's encoding.
        labels: (N,) int32 class ids (instance bits removed), or None when unlabelled.
        ring: (N,) int16 laser channel (0 = lowest) from the file's ring column, or as
            recovered from the whole file by the beam table (`lads.diagnose.data.beams`); None
            when neither has been done.
        index: (N,) int64 row of each point in the scan file.
    """

    relpath: str
    xyz: npt.NDArray[np.float64]
    intensity: npt.NDArray[np.float32]
    labels: npt.NDArray[np.int32] | None
    ring: npt.NDArray[np.int16] | None
    index: npt.NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def range_m(self) -> npt.NDArray[np.float64]:
        """(N,) float64 distance of every point from the sensor, m."""
        out: npt.NDArray[np.float64] = np.sqrt(np.einsum("ij,ij->i", self.xyz, self.xyz))
        return out

    def take(self, idx: npt.NDArray[np.int64]) -> Scan:
        """The scan restricted to points `idx` (in that order); file rows are kept."""
        return Scan(
            relpath=self.relpath,
            xyz=self.xyz[idx],
            intensity=self.intensity[idx],
            labels=None if self.labels is None else self.labels[idx],
            ring=None if self.ring is None else self.ring[idx],
            index=self.index[idx],
        )


@dataclass(frozen=True, slots=True)
class _TreeSource:
    """How to read one tree: its reader and items."""

    root: Path
    reader: Reader
    items: dict[str, Item]
    labelled: bool


@dataclass(frozen=True, slots=True)
class TreePair:
    """A simulated and a real tree of one source and sensor, ready to be read scan by scan.

    Attributes:
        source: "semantickitti", "nuscenes" or "wads".
        sim_root, real_root: the tree roots.
        profile: sensor profile of both trees.
        sensor: what the fitter needs to know about that sensor.
        sim_scans, real_scans: sorted scan relpaths of each tree (equal when paired).
        paired: both trees hold the same scans, rendered from the same poses.
    """

    source: str
    sim_root: Path
    real_root: Path
    profile: SensorProfile
    sensor: SensorInfo
    sim_scans: tuple[str, ...]
    real_scans: tuple[str, ...]
    paired: bool
    _trees: dict[str, _TreeSource] = field(repr=False, compare=False)

    def read_scan(self, tree: Tree, relpath: str) -> Scan:
        """Scan `relpath` of the "sim" or "real" tree (see `Scan`).

        Raises:
            DiagnoseError: unknown tree or relpath, a file whose size or intensities do not
                fit the source's format and sensor, or an invalid ring column.
            ReaderError: the reader cannot read the item (message names the file).
        """
        src = self._source(tree)
        self._item(src, tree, relpath)  # refuses an unknown relpath, naming the tree's scans
        return _read(self.source, self.profile, tree, src, relpath)

    def reader(self, tree: Tree) -> Reader:
        """The reader of the "sim" or "real" tree."""
        return self._source(tree).reader

    def read_frame(self, tree: Tree, relpath: str) -> Frame:
        """Scan `relpath` as its reader reads it (every row, labels as stored)."""
        src = self._source(tree)
        return src.reader.read(self._item(src, tree, relpath))

    def _source(self, tree: Tree) -> _TreeSource:
        if tree not in self._trees:
            raise DiagnoseError(f"tree {tree!r}: expected 'sim' or 'real'.")
        return self._trees[tree]

    def _item(self, src: _TreeSource, tree: Tree, relpath: str) -> Item:
        if relpath not in src.items:
            scans = self.sim_scans if tree == "sim" else self.real_scans
            raise DiagnoseError(
                f"{src.root}: no scan {relpath!r} in the {tree} tree; pass one of its "
                f"{len(scans)} scans (e.g. {list(scans[:_EXAMPLES])})."
            )
        return src.items[relpath]


def open_trees(
    sim_root: str | Path, real_root: str | Path, source: str, *, paired: bool
) -> TreePair:
    """Open the simulated and the real tree of `source` and check they can be compared.

    Args:
        sim_root, real_root: tree roots as the source's reader takes them (SemanticKITTI and
            WADS: the folder holding `sequences/`; nuScenes: the dataroot, or any folder of
            bare `*.pcd.bin` scans).
        source: "semantickitti", "nuscenes" or "wads" (both trees are of this source).
        paired: the simulation was rendered from the real poses, scan for scan; both trees
            must then hold the same relpaths.

    Returns:
        TreePair. The first scan of each tree has been read to check the sensor.

    Raises:
        ConfigError: unknown source.
        DiagnoseError: a root is missing or holds no scans of `source`; paired trees with
            different relpaths; scans that look like another sensor or format.
    """
    if source not in SOURCES:
        raise ConfigError(f"source {source!r}: expected one of {', '.join(SOURCES)}.")
    sim = _open_tree(Path(sim_root), source, "sim")
    real = _open_tree(Path(real_root), source, "real")
    sim_scans, real_scans = tuple(sorted(sim.items)), tuple(sorted(real.items))
    if paired and sim_scans != real_scans:
        raise DiagnoseError(_relpath_mismatch(sim, real, sim_scans, real_scans))
    if not paired:
        _check_both_labelled(sim, real)
    profile = load_profile(_profile_name(sim))
    labelled = sim.labelled or real.labelled
    enc = profile.intensity
    sensor = SensorInfo(
        profile=profile.name,
        n_rings=profile.channels,
        encoding_kind=enc.kind,
        step=enc.step,
        max_value=enc.max_value,
        full_scale=enc.reflectivity_full_scale,
        calibrated=profile.name in _CALIBRATED_PROFILES,
        has_ring_column=profile.has_ring_column,
        label_set=source if labelled else None,
    )
    pair = TreePair(
        source,
        sim.root,
        real.root,
        profile,
        sensor,
        sim_scans,
        real_scans,
        paired,
        {"sim": sim, "real": real},
    )
    pair.read_scan("sim", sim_scans[0])
    pair.read_scan("real", real_scans[0])
    return pair


def _check_both_labelled(sim: _TreeSource, real: _TreeSource) -> None:
    """DiagnoseError when one unpaired tree has labels and the other has not."""
    if sim.labelled == real.labelled:
        return
    bare = sim if not sim.labelled else real
    raise DiagnoseError(
        f"{bare.root}: the {'sim' if bare is sim else 'real'} tree has no label file for "
        "every scan, the other has: an unpaired comparison matches beams of the same class "
        "(and range and incidence), so give both trees labels (or neither)."
    )


def _open_tree(root: Path, source: str, tree: str) -> _TreeSource:
    if not root.is_dir():
        raise DiagnoseError(
            f"{root}: the {tree} tree root does not exist or is not a folder; pass the root "
            f"of a {source} tree."
        )
    name = source
    if source == "nuscenes" and not any(d.is_dir() for d in root.glob("v1.0-*")):
        name = "nuscenes-scans"  # loose scans: no devkit tables to read
    reader = get_reader(name, root)
    try:
        items = reader.items()
    except DatasetNotFoundError as exc:
        tables = " (or pass a dataroot with its v1.0-* table folder)" if name != source else ""
        raise DiagnoseError(f"the {tree} tree holds no {source} scans: {exc}{tables}") from exc
    labelled = all(item.label_relpath is not None for item in items)
    return _TreeSource(reader.root, reader, {it.relpath: it for it in items}, labelled)


def _profile_name(tree: _TreeSource) -> str:
    return tree.reader.sensor


def _relpath_mismatch(
    sim: _TreeSource, real: _TreeSource, sim_scans: tuple[str, ...], real_scans: tuple[str, ...]
) -> str:
    only_sim = sorted(set(sim_scans) - set(real_scans))
    only_real = sorted(set(real_scans) - set(sim_scans))
    sides = []
    if only_sim:
        sides.append(
            f"{len(only_sim)} of {len(sim_scans)} scans of the sim tree {sim.root} are missing "
            f"from the real tree (e.g. {only_sim[:_EXAMPLES]})"
        )
    if only_real:
        sides.append(
            f"{len(only_real)} of {len(real_scans)} scans of the real tree {real.root} are "
            f"missing from the sim tree (e.g. {only_real[:_EXAMPLES]})"
        )
    return (
        f"paired trees must hold the same scans, but {' and '.join(sides)}. Render the "
        "simulation from the real scans' poses with the same relative paths, or compare the "
        "trees unpaired."
    )


def _read(source: str, profile: SensorProfile, tree: str, src: _TreeSource, relpath: str) -> Scan:
    path = src.root / relpath
    columns: tuple[str, ...] = src.reader.columns
    _check_size(path, columns, source, profile, tree)
    try:
        frame = src.reader.read(src.items[relpath])
    except CorruptItemError as exc:  # the reader's own check: say which tree, and why
        raise DiagnoseError(
            f"the {tree} tree: {exc} Both trees must hold {source} scans of the "
            f"'{profile.name}' sensor: the trees look like different sensors or formats."
        ) from exc
    points, columns, labels_raw = frame.points, frame.columns, frame.labels
    intensity = np.array(points[:, columns.index("intensity")], dtype=np.float32)
    try:
        profile.intensity.validate(intensity, f"{path} ({tree} tree)")
    except IntensityEncodingError as exc:
        raise DiagnoseError(
            f"{exc} Both trees must hold {source} scans of the '{profile.name}' sensor; a "
            f"scan written with another column layout than {len(columns)} float32 columns "
            f"({', '.join(columns)}) shows up this way too."
        ) from exc
    ring = None
    if "ring" in columns:
        ring = _checked_ring(points[:, columns.index("ring")], path, tree, profile)
    xyz = points[:, :3].astype(np.float64)
    keep = np.flatnonzero(np.sqrt(np.einsum("ij,ij->i", xyz, xyz)) > MIN_RANGE_M)
    labels = None
    if labels_raw is not None:
        label_set = src.reader.label_set
        ids = labels_raw.astype(np.int64) if label_set is None else class_ids(labels_raw, label_set)
        labels = ids.astype(np.int32)[keep]
    return Scan(
        relpath=relpath,
        xyz=xyz[keep],
        intensity=intensity[keep],
        labels=labels,
        ring=None if ring is None else ring[keep],
        index=keep.astype(np.int64),
    )


def _check_size(
    path: Path, columns: tuple[str, ...], source: str, profile: SensorProfile, tree: str
) -> None:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise DiagnoseError(
            f"{path}: cannot read the {tree} tree's scan ({exc.strerror or exc}); check that "
            "it exists and is readable."
        ) from exc
    record = 4 * len(columns)
    if size % record == 0:
        return
    fits = [c for c in range(3, 9) if size % (4 * c) == 0]
    raise DiagnoseError(
        f"{path}: {size} bytes is not a whole number of {len(columns)}-column float32 records "
        f"({', '.join(columns)}) as {source} scans of the '{profile.name}' sensor have"
        f"{f'; it would fit {fits} columns' if fits else ''}. The {tree} tree looks written for "
        f"another sensor or format: write both trees in the {source} layout."
    )


def _checked_ring(
    column: npt.NDArray[np.float32], path: Path, tree: str, profile: SensorProfile
) -> npt.NDArray[np.int16]:
    bad = not_lasers(column, profile.channels)
    if bad.any():
        raise DiagnoseError(
            f"{path}: {int(bad.sum())} of {column.size} ring values in the {tree} tree's scan "
            f"are not integers in [0, {profile.channels}) (e.g. {column[bad][:3].tolist()}), "
            f"so it has no usable ring column where the '{profile.name}' sensor writes one. "
            "The trees look like different sensors: write the laser channel (0 = lowest beam) "
            "in the ring column of both."
        )
    return column.astype(np.int16)
