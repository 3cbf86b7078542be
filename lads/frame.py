"""What flows through a pipeline: one item (a scan and its files) and its frame.

An *item* names one scan of a source tree and every per-scan file that belongs to it; a
*frame* is the item's content in memory after reading (and after each stage). Stages see
frames only; readers turn items into frames and frames back into file bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from lads.physics.result import Outcome

# The frame column that holds each point's laser (channel), where the format stores one.
RING_COLUMN = "ring"


def not_lasers(ring: npt.ArrayLike, channels: int) -> npt.NDArray[np.bool_]:
    """(N,) bool: the ring values that are no laser number 0..channels-1 (not finite, not
    whole, or out of range); the one rule every ring check applies."""
    arr = np.asarray(ring, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return ~np.isfinite(arr) | (arr != np.rint(arr)) | (arr < 0) | (arr >= channels)


@dataclass(frozen=True, slots=True)
class Item:
    """One scan of a source tree, by relative paths (POSIX, relative to the source root).

    Attributes:
        dataset: reader name (a key of `lads.readers.READERS`).
        relpath: the scan file; also the item's identity within the dataset.
        label_relpath: the per-point label file, or None when the item has none.
        extra_relpaths: further per-point files as (role, relpath), e.g. Voxelscape's
            ("orig_labels", ...), ("orig_sublabels", ...).
        meta: reader-specific (key, value) strings, e.g. the nuScenes sample_data token.
    """

    dataset: str
    relpath: str
    label_relpath: str | None = None
    extra_relpaths: tuple[tuple[str, str], ...] = ()
    meta: tuple[tuple[str, str], ...] = ()

    @property
    def item_id(self) -> str:
        """Stable text id, `dataset:relpath`; sorts like the source tree."""
        return f"{self.dataset}:{self.relpath}"

    def source_relpaths(self) -> tuple[str, ...]:
        """Every source file of this item: scan, labels, extras (in that order)."""
        paths = [self.relpath]
        if self.label_relpath is not None:
            paths.append(self.label_relpath)
        paths.extend(p for _, p in self.extra_relpaths)
        return tuple(paths)


def _empty_index() -> npt.NDArray[np.int64]:
    return np.zeros(0, dtype=np.int64)


@dataclass(frozen=True, slots=True)
class Frame:
    """One scan in memory, with the provenance of every point relative to the source scan.

    Attributes:
        item: the source item.
        sensor: sensor profile name (`lads profiles`).
        columns: names of the point columns, e.g. ("x", "y", "z", "intensity", "ring").
        points: (M, C) float32; x, y, z in m (sensor frame), then intensity in the sensor's
            encoding, then any further columns of the source format.
        labels: (M,) per-point labels in the dataset's dtype (uint32 SemanticKITTI-style,
            uint8 nuScenes lidarseg), or None.
        extra_labels: further per-point arrays by role, each (M,), e.g. Voxelscape int32
            orig_labels.
        source_index: (M,) int64, row of the source scan each point came from.
        outcome: (M,) uint8 `lads.physics.result.Outcome` per point (KEPT when read).
        lost_index: (K,) int64 source rows that no longer return; M + K = n_source.
        n_source: N, the point count of the source scan.
        conditions: what earlier stages did to the whole frame, as (key, value) pairs,
            e.g. ("style", "snow"), ("extinction_per_m", 0.004); later stages read them.
        window: relpaths of the scans a sensor transfer drew its points from, in scan
            order (the item's own among them); () when every point comes from the item's
            own scan.
        source_scan: (M,) int16 index into `window` of the scan each point's source_index
            is a row of; empty when `window` is ().
    """

    item: Item
    sensor: str
    columns: tuple[str, ...]
    points: npt.NDArray[np.float32]
    labels: npt.NDArray[np.generic] | None
    extra_labels: dict[str, npt.NDArray[np.generic]] = field(default_factory=dict)
    source_index: npt.NDArray[np.int64] = field(default_factory=_empty_index)
    outcome: npt.NDArray[np.uint8] = field(default_factory=lambda: np.zeros(0, np.uint8))
    lost_index: npt.NDArray[np.int64] = field(default_factory=_empty_index)
    n_source: int = -1
    conditions: tuple[tuple[str, str | float], ...] = ()
    window: tuple[str, ...] = ()
    source_scan: npt.NDArray[np.int16] = field(default_factory=lambda: np.zeros(0, np.int16))

    def condition(self, key: str, default: str | float | None = None) -> str | float | None:
        """The value an earlier stage recorded under `key`, else `default`."""
        return dict(self.conditions).get(key, default)

    @classmethod
    def from_source(
        cls,
        item: Item,
        sensor: str,
        columns: tuple[str, ...],
        points: npt.NDArray[np.float32],
        labels: npt.NDArray[np.generic] | None,
        extra_labels: dict[str, npt.NDArray[np.generic]] | None = None,
    ) -> Frame:
        """A frame as read: every point KEPT, source_index = 0..N-1."""
        n = int(points.shape[0])
        return cls(
            item=item,
            sensor=sensor,
            columns=columns,
            points=points,
            labels=labels,
            extra_labels=dict(extra_labels or {}),
            source_index=np.arange(n, dtype=np.int64),
            outcome=np.full(n, Outcome.KEPT, dtype=np.uint8),
            lost_index=_empty_index(),
            n_source=n,
        )

    @property
    def xyz(self) -> npt.NDArray[np.float32]:
        """(M, 3) float32 view of the coordinates, m."""
        return self.points[:, :3]

    @property
    def intensity(self) -> npt.NDArray[np.float32]:
        """(M,) float32 view of the intensity column."""
        return self.points[:, 3]

    def select(
        self,
        rows: npt.NDArray[np.int64],
        *,
        outcome: npt.NDArray[np.uint8],
        lost_rows: npt.NDArray[np.int64],
        points: npt.NDArray[np.float32],
    ) -> Frame:
        """The frame a stage returns: `rows` of this frame survive, in order, as `points`.

        Provenance composes: source_index maps through this frame's, an outcome never
        becomes milder (KEPT < ATTENUATED < PARTICLE), and lost rows join the lost set.

        Args:
            rows: (M',) int64 increasing rows of this frame that still return.
            outcome: (M',) uint8 outcome of this stage per surviving row.
            lost_rows: (K',) int64 rows of this frame that no longer return.
            points: (M', C) float32 new point values (xyz, intensity, other columns).
        """
        lost = np.concatenate([self.lost_index, self.source_index[lost_rows]])
        lost.sort()
        return replace(
            self,
            points=points,
            labels=None if self.labels is None else self.labels[rows],
            extra_labels={k: v[rows] for k, v in self.extra_labels.items()},
            source_index=self.source_index[rows],
            source_scan=self.source_scan[rows] if self.window else self.source_scan,
            outcome=np.maximum(self.outcome[rows], outcome).astype(np.uint8),
            lost_index=lost,
        )
