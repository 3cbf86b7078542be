"""The sensor stage: a frame as another LiDAR would have scanned it (docs/transfer.md).

The stage sees the frame and its window: the surfels of neighbouring scans of the sequence
with their poses, which the worker reads (`lads.worker`; the stage does no I/O). Called on
a frame alone, the window is the frame's own scan. Every output point is a beam of the
target sensor (`Outcome.RESAMPLED`): its source index is the row of the return whose surface
it hit, in the window scan its `source_scan` names. Labels follow the surface hit; the
intensity is the surface's albedo seen by the target at its incidence, in the target's
encoding; a nuScenes-style `ring` column gets the target's channel; further per-point arrays
(nuScenes panoptic) take the value of the return each beam hit. The points keep the frame's
columns, or take the target's native record (`columns`, set from the pipeline's
`writer.point_format`, `lads.stages.build_stages`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from lads.config import StageConfig
from lads.errors import ConfigError, InputDataError
from lads.frame import RING_COLUMN, Frame
from lads.physics.result import Outcome
from lads.readers import label_set_for
from lads.sensors.profile import load_profile
from lads.transfer.scan import WindowScan, transfer_surfels, window_surfels
from lads.transfer.surfels import Surfels
from lads.transfer.window import DEFAULT_NEIGHBOURS

# Bump when the stage's output bytes change for the same input.
# 4: normals along the line of far ground, its surfels stretched further; 5: hits in the
# centre scan's free space carved; 6: the target detects what the source detected (the
# least albedo its detection implies); 7: hits in front of the surface a centre beam saw in
# its own footprint carved
SENSOR_STAGE_VERSION = "7"
# Point columns the stage knows how to fill; any other column of a source format is refused.
_KNOWN_COLUMNS = ("x", "y", "z", "intensity", RING_COLUMN)


@dataclass(frozen=True, slots=True)
class PreparedScan:
    """What a window scan lends: its surfels (in its sensor frame) and its further per-point
    arrays by role (e.g. nuScenes panoptic), which follow the return each beam hits."""

    surfels: Surfels
    extra_labels: dict[str, npt.NDArray[np.generic]]


@dataclass(frozen=True, slots=True)
class SensorStage:
    """Scan each frame again with the `target` sensor, from the frame's own pose.

    Attributes:
        name: "sensor".
        target: the target sensor profile (`lads profiles`, or a profile YAML path).
        neighbours: neighbouring scans of the sequence in each frame's window
            (`lads.transfer.window`); 0 transfers each frame from its own scan.
        columns: the point columns written (the target's native record when the pipeline
            writes point_format "target"); () keeps the frame's own columns.
    """

    name: str
    target: str
    neighbours: int = DEFAULT_NEIGHBOURS
    version: str = SENSOR_STAGE_VERSION
    columns: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.columns and not _fills(self.columns):
            raise ConfigError(
                f"sensor stage: the point record {self.columns} has columns the stage cannot "
                f"fill; it writes {_KNOWN_COLUMNS} (x, y, z, intensity first). Build with "
                "--point-format source."
            )

    @classmethod
    def from_config(cls, config: StageConfig) -> SensorStage:
        return cls(name=config.stage, **config.params)

    def prepare(self, frame: Frame) -> PreparedScan:
        """The surfels of one scan of a window, in its sensor frame, and its per-point arrays
        (deterministic: the worker computes them once per scan and lends them to every
        window that holds it)."""
        _check_columns(frame)
        # Albedo comes from the intensity: values of another encoding would saturate silently.
        profile = load_profile(frame.sensor)
        profile.intensity.validate(frame.intensity, f"{frame.item.item_id}: intensity")
        ring = (
            frame.points[:, frame.columns.index(RING_COLUMN)]
            if RING_COLUMN in frame.columns
            else None
        )
        scan = WindowScan(frame.xyz, frame.intensity, frame.labels, ring, np.eye(4))
        label_set = label_set_for(frame.item.dataset)
        surfels = window_surfels(scan, profile, label_set)
        return PreparedScan(surfels, dict(frame.extra_labels))

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """The frame transferred from its own scan alone (a window of one)."""
        return self.call_window(
            frame, [self.prepare(frame)], [np.eye(4)], 0, (frame.item.relpath,), rng
        )

    def call_window(
        self,
        frame: Frame,
        parts: Sequence[PreparedScan],
        poses: Sequence[npt.NDArray[np.float64]],
        centre: int,
        window: tuple[str, ...],
        rng: np.random.Generator,
    ) -> Frame:
        """The frame transferred from its window.

        Args:
            frame: the window's centre scan as read.
            parts: `prepare` of every window scan, in scan order.
            poses: (4, 4) float64 sensor -> world pose of every window scan.
            centre: index of `frame` in the window.
            window: relpaths of the window scans (recorded in the provenance).
            rng: randomness of the target's range noise.
        """
        _check_columns(frame)
        out = transfer_surfels(
            [p.surfels for p in parts],
            poses,
            centre,
            load_profile(frame.sensor),
            load_profile(self.target),
            rng,
            label_set=label_set_for(frame.item.dataset),
        )
        columns = self.columns or frame.columns
        points = np.zeros((out.xyz.shape[0], len(columns)), np.float32)
        points[:, :3] = out.xyz
        points[:, 3] = out.intensity
        if RING_COLUMN in columns:
            points[:, columns.index(RING_COLUMN)] = out.ring
        labels = None if frame.labels is None else out.labels.astype(frame.labels.dtype)
        m = out.xyz.shape[0]
        return replace(
            frame,
            sensor=self.target,
            columns=columns,
            points=points,
            labels=labels,
            extra_labels=_lent_extras(frame, parts, out.source_frame, out.source_point),
            source_index=out.source_point,
            outcome=np.full(m, Outcome.RESAMPLED, np.uint8),
            lost_index=np.zeros(0, np.int64),
            window=window,
            source_scan=out.source_frame.astype(np.int16),
            conditions=frame.conditions + (("source_sensor", frame.sensor),),
        )


def _lent_extras(
    frame: Frame,
    parts: Sequence[PreparedScan],
    scan: npt.NDArray[np.int32],
    row: npt.NDArray[np.int64],
) -> dict[str, npt.NDArray[np.generic]]:
    """Each per-point array of the frame for the new beams: the value of the return each
    beam hit, in the scan it came from (0 where that scan lacks the array)."""
    out = {}
    for role, values in frame.extra_labels.items():
        lent = np.zeros(len(row), dtype=values.dtype)
        for k, part in enumerate(parts):
            theirs = part.extra_labels.get(role)
            mine = scan == k
            if theirs is not None and mine.any():
                lent[mine] = theirs[row[mine]]
        out[role] = lent
    return out


def _fills(columns: tuple[str, ...]) -> bool:
    """Whether the stage can fill every column: x, y, z, intensity first, then only ring."""
    return columns[:4] == _KNOWN_COLUMNS[:4] and set(columns) <= set(_KNOWN_COLUMNS)


def _check_columns(frame: Frame) -> None:
    if not _fills(frame.columns):
        raise InputDataError(
            f"{frame.item.relpath}: the sensor stage writes the columns {_KNOWN_COLUMNS}, but "
            f"this source has {frame.columns}; transfer a source of x, y, z, intensity "
            "(and ring)."
        )
