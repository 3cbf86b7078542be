"""Weather stages: rain, snow and fog from `lads.physics.weather` applied to a Frame."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.config import StageConfig
from lads.frame import Frame
from lads.physics import weather as wx
from lads.physics.result import WeatherResult
from lads.sensors.profile import SensorProfile

# Bump when the physics changes the bytes produced for the same input and seed.
WEATHER_STAGE_VERSION = "6"


@dataclass(frozen=True, slots=True)
class WeatherStage:
    """One weather at one strength on one frame.

    Attributes:
        name: "rain", "snow" or "fog".
        rate_mm_h: rain or snow rate in mm/h (water equivalent for snow); None for fog.
        visibility_m: fog meteorological optical range in m; None for rain and snow.
        mode: "strongest", "last" or "dual" return (dual: two points where a beam's strongest
            and last returns differ, labels following the beam).
        severity: the preset the strength came from (lads.physics.severity), or None;
            recorded only: the physics runs on rate_mm_h / visibility_m.
        settings: "lads" (the shipped physics) or "lisa" (LISA's published model, rain and
            snow), `lads.physics.weather.SETTINGS`.
        detection: None (the settings' own rule: the sensor's detection limit for "lads",
            LISA's fixed threshold for "lisa"), "sensor", "frame" or a fixed threshold in
            reflectivity / m^2 (`lads.physics.detection`, docs/physics.md §9.7).
    """

    name: str
    rate_mm_h: float | None = None
    visibility_m: float | None = None
    mode: str = "strongest"
    severity: str | None = None
    settings: str = "lads"
    detection: str | float | None = None
    version: str = WEATHER_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> WeatherStage:
        return cls(name=config.stage, **config.params)

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """Points that still return, with weather intensities; labels and extra columns
        (e.g. the nuScenes ring) follow each point's source beam."""
        result = self.simulate(frame.xyz, frame.intensity, frame.sensor, rng)
        points = frame.points[result.source_index]
        points[:, :3] = result.xyz
        points[:, 3] = result.intensity
        out = frame.select(
            result.source_index, outcome=result.outcome, lost_rows=result.lost_index, points=points
        )
        conditions = (("style", self.name), ("extinction_per_m", float(result.extinction_per_m)))
        return replace(out, conditions=out.conditions + conditions)

    def simulate(
        self,
        xyz: npt.NDArray[np.floating[Any]],
        intensity: npt.NDArray[np.floating[Any]],
        sensor: str | SensorProfile,
        rng: np.random.Generator,
    ) -> WeatherResult:
        """This weather on (N, 3) coordinates in m and (N,) intensities in the sensor's
        encoding, with the stage's settings and detection rule (`lads weather` runs it on a
        lone scan file)."""
        params = wx.settings_for(self.name, self.settings)
        if self.detection is not None:
            params = replace(params, detection_threshold=self.detection)
        strength = (
            {"visibility_m": float(self.visibility_m)}  # type: ignore[arg-type]
            if self.name == "fog"
            else {"rate_mm_h": float(self.rate_mm_h)}  # type: ignore[arg-type]
        )
        simulate: Any = {"fog": wx.fog, "rain": wx.rain, "snow": wx.snow}[self.name]
        return simulate(
            xyz, intensity, sensor=sensor, rng=rng, mode=self.mode, params=params, **strength
        )
