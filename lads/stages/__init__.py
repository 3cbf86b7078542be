"""Pipeline stages: pure functions of (frame, rng) -> frame, built from a StageConfig.

STAGES is the one explicit table of stage names; `build_stage` turns a config entry into a
callable stage object, `build_stages` every stage of a pipeline.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Protocol, cast

from lads.config import PipelineConfig, StageConfig
from lads.errors import ConfigError
from lads.stages.base import Stage
from lads.stages.intensity import IntensityStage
from lads.stages.sensor import SensorStage
from lads.stages.sensor_faults import (
    BeamMissingStage,
    CrosstalkStage,
    IncompleteEchoStage,
    MotionDistortionStage,
)
from lads.stages.weather import WeatherStage
from lads.stages.wet_ground import WetGroundStage


class StageClass(Protocol):
    """A stage class as `build_stage` uses it: its `from_config` classmethod."""

    def from_config(self, config: StageConfig) -> object: ...


STAGES: dict[str, StageClass] = {
    "rain": WeatherStage,
    "snow": WeatherStage,
    "fog": WeatherStage,
    "intensity": IntensityStage,
    "wet_ground": WetGroundStage,
    "sensor": SensorStage,
    "beam_missing": BeamMissingStage,
    "motion_distortion": MotionDistortionStage,
    "incomplete_echo": IncompleteEchoStage,
    "crosstalk": CrosstalkStage,
}


def build_stage(config: StageConfig) -> Stage:
    """The stage object for one pipeline entry. Raises ConfigError for unknown names."""
    cls = STAGES.get(config.stage)
    if cls is None:
        raise ConfigError(f"unknown stage {config.stage!r}; expected one of {sorted(STAGES)}.")
    # Every stage class is a frozen dataclass: its name and version are read-only, which
    # mypy's reading of the Stage protocol (plain, settable attributes) does not accept.
    return cast(Stage, cls.from_config(config))


def check_sensor(stages: tuple[Stage, ...], sensor: str) -> None:
    """ConfigError, before any frame is built, when a stage cannot run on frames of
    `sensor` (a learned weather intensity without that sensor's calibration)."""
    styles = tuple(s.name for s in stages if isinstance(s, WeatherStage))
    for stage in stages:
        if isinstance(stage, IntensityStage):
            stage.check_sensor(sensor, styles)


def build_stages(pipeline: PipelineConfig) -> tuple[Stage, ...]:
    """Every stage of `pipeline`, in order; its sensor stage writes the point record the
    pipeline's writer names (`PipelineConfig.point_record`: the target's native one, or
    the frame's own columns).

    Raises:
        ConfigError: an unknown stage, a record the sensor stage cannot fill, or a weather
            intensity model with no weather stage before it (to read its style from).
    """
    stages = [build_stage(s) for s in pipeline.stages]
    for k, stage in enumerate(stages):
        before = any(isinstance(s, WeatherStage) for s in stages[:k])
        if isinstance(stage, IntensityStage) and stage.reads_style() and not before:
            raise ConfigError(
                f"pipeline '{pipeline.variant}': the weather intensity model "
                f"'{stage.model}' takes its style from a rain, snow or fog stage before it; "
                "put the intensity stage after one, or give it a target."
            )
    record = pipeline.point_record()
    if record is None:
        return tuple(stages)
    return tuple(
        cast(Stage, replace(s, columns=record.columns)) if isinstance(s, SensorStage) else s
        for s in stages
    )
