"""Wet-ground stage: a water film on the frame's road-like points (`lads.physics.wet_ground`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lads.config import StageConfig
from lads.frame import Frame
from lads.physics.wet_ground import WetGroundParams, wet_ground
from lads.readers import label_set_for

# Bump when the physics changes the bytes produced for the same input and seed.
WET_GROUND_STAGE_VERSION = "1"


@dataclass(frozen=True, slots=True)
class WetGroundStage:
    """A water film of one thickness on one frame.

    Attributes:
        name: "wet_ground".
        water_film_mm: film thickness, mm (0 = dry).
        severity: the preset the thickness came from (lads.physics.severity), or None.
        detection: None ("sensor"), "sensor", "frame" or a fixed threshold (docs/physics.md §9.7).
    """

    name: str
    water_film_mm: float = 0.0
    severity: str | None = None
    detection: str | float | None = None
    version: str = WET_GROUND_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> WetGroundStage:
        return cls(name=config.stage, **config.params)

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """Wet road-like points darkened (or lost); every other point unchanged. A frame
        without labels cannot tell road from anything else: it passes unchanged, and its
        conditions say so."""
        label_set = label_set_for(frame.item.dataset)
        if frame.labels is None or label_set is None:
            return replace(frame, conditions=frame.conditions + (("wet_ground", "no labels"),))
        result = wet_ground(
            frame.xyz,
            frame.intensity,
            frame.labels,
            label_set,
            sensor=frame.sensor,
            rng=rng,
            params=WetGroundParams(float(self.water_film_mm)),
            detection="sensor" if self.detection is None else self.detection,
        )
        points = frame.points[result.source_index]
        points[:, 3] = result.intensity
        out = frame.select(
            result.source_index, outcome=result.outcome, lost_rows=result.lost_index, points=points
        )
        conditions = (("wet_ground_water_film_mm", float(self.water_film_mm)),)
        return replace(out, conditions=out.conditions + conditions)
