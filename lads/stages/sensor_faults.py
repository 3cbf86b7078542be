"""Sensor-fault stages: dead lasers, a motion-distorted sweep (`lads.physics.sensor_faults`),
returns lost to dark glossy paint and another LiDAR's false returns (`lads.physics.echo_faults`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lads.config import StageConfig
from lads.errors import ConfigError
from lads.frame import RING_COLUMN, Frame
from lads.physics import sensor_faults as faults
from lads.physics.echo_faults import crosstalk, incomplete_echo
from lads.physics.projection import MIN_RANGE_M, channels_of, range_m
from lads.physics.result import WeatherResult
from lads.readers import label_set_for
from lads.sensors.profile import SensorProfile, load_profile

# Bump when the output bytes change for the same input and seed.
SENSOR_FAULT_STAGE_VERSION = "1"


def _apply(
    frame: Frame, result: WeatherResult, conditions: tuple[tuple[str, str | float], ...]
) -> Frame:
    points = frame.points[result.source_index]
    points[:, :3] = result.xyz
    points[:, 3] = result.intensity
    out = frame.select(
        result.source_index, outcome=result.outcome, lost_rows=result.lost_index, points=points
    )
    return replace(out, conditions=out.conditions + conditions)


def frame_channels(frame: Frame, profile: SensorProfile) -> np.ndarray:
    """(M,) int64 laser of each point: the ring column when the frame has one, else the
    nearest elevation of the profile's table (`lads.physics.projection.channels_of`, which
    refuses a ring outside the profile's channels)."""
    ring = (
        frame.points[:, frame.columns.index(RING_COLUMN)] if RING_COLUMN in frame.columns else None
    )
    return channels_of(frame.xyz.astype(np.float64), profile, ring)


@dataclass(frozen=True, slots=True)
class BeamMissingStage:
    """Whole lasers fail: every return of `lost_channel_share` of the channels is lost.

    Attributes:
        name: "beam_missing".
        lost_channel_share: share of the sensor's lasers that fail, in [0, 1].
        channels: the failed channel ids; None draws them per frame from the frame's rng.
        severity: the preset the share came from (lads.physics.severity), or None.
    """

    name: str
    lost_channel_share: float = 0.0
    channels: tuple[int, ...] | None = None
    severity: str | None = None
    version: str = SENSOR_FAULT_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> BeamMissingStage:
        params = dict(config.params)
        if params.get("channels") is not None:
            params["channels"] = tuple(int(c) for c in params["channels"])
        return cls(name=config.stage, **params)

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """The frame without the dead lasers' returns; every other point unchanged."""
        profile = load_profile(frame.sensor)
        if self.channels is None:
            dead = faults.dead_channels(profile.channels, float(self.lost_channel_share), rng)
        else:
            dead = np.asarray(self.channels, dtype=np.int64)
        result = faults.beam_missing(
            frame.xyz, frame.intensity, frame_channels(frame, profile), dead
        )
        listed = " ".join(str(int(c)) for c in dead)
        return _apply(frame, result, (("dead_channels", listed),))


@dataclass(frozen=True, slots=True)
class MotionDistortionStage:
    """The sweep as an uncompensated sensor reports it at `speed_m_s` (docs/augment.md §3).

    Attributes:
        name: "motion_distortion".
        speed_m_s: forward speed, m/s.
        yaw_rate_deg_s: turn rate about z, deg/s (positive: to the left).
        sweep_period_s: one revolution, s; None = the sensor profile's.
        seam_azimuth_deg: where the sweep starts and ends, deg; None = behind the vehicle
            (the profile's forward azimuth + 180).
        severity: the preset the speed came from, or None.
    """

    name: str
    speed_m_s: float = 0.0
    yaw_rate_deg_s: float = 0.0
    sweep_period_s: float | None = None
    seam_azimuth_deg: float | None = None
    severity: str | None = None
    version: str = SENSOR_FAULT_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> MotionDistortionStage:
        return cls(name=config.stage, **config.params)

    def timing(self, profile: SensorProfile) -> tuple[float, float, float]:
        """(sweep period s, forward azimuth deg, seam azimuth deg) for this sensor.

        Raises:
            ConfigError: the profile lacks a value the stage was not given.
        """
        period = self.sweep_period_s if self.sweep_period_s is not None else profile.sweep_period_s
        forward = profile.forward_azimuth_deg
        if period is None or forward is None:
            raise ConfigError(
                f"motion_distortion: sensor profile '{profile.name}' has no sweep_period_s or "
                "forward_azimuth_deg; add them to the profile (see lads/sensors/hdl64e.yaml) "
                "or pass sweep_period_s."
            )
        seam = self.seam_azimuth_deg if self.seam_azimuth_deg is not None else forward + 180.0
        return float(period), float(forward), float(seam)

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """Every point moved to where the moving sensor reported it; zero-range rows (no
        return) stay where they are. Uses no randomness."""
        period, forward, seam = self.timing(load_profile(frame.sensor))
        result = faults.motion_distortion(
            frame.xyz,
            frame.intensity,
            speed_m_s=float(self.speed_m_s),
            yaw_rate_deg_s=float(self.yaw_rate_deg_s),
            sweep_period_s=period,
            forward_azimuth_deg=forward,
            seam_azimuth_deg=seam,
        )
        empty = range_m(frame.xyz) <= MIN_RANGE_M
        if empty.any():
            result.xyz[empty] = frame.xyz[empty]
            result.outcome[empty] = 0
        conditions = (("speed_m_s", float(self.speed_m_s)), ("sweep_period_s", period))
        return _apply(frame, result, conditions)


@dataclass(frozen=True, slots=True)
class IncompleteEchoStage:
    """Vehicles repainted with a darker paint: weak returns of clear-coat classes are lost.

    Attributes:
        name: "incomplete_echo".
        paint_reflectance: 905 nm reflectance of the new paint, in (0, 1].
        severity: the preset the reflectance came from, or None.
        detection: None ("sensor"), "sensor", "frame" or a fixed threshold.
    """

    name: str
    paint_reflectance: float = 1.0
    severity: str | None = None
    detection: str | float | None = None
    version: str = SENSOR_FAULT_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> IncompleteEchoStage:
        return cls(name=config.stage, **config.params)

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """Clear-coat points dimmed or lost; a frame without labels passes unchanged and
        its conditions say so."""
        label_set = label_set_for(frame.item.dataset)
        if frame.labels is None or label_set is None:
            return replace(frame, conditions=frame.conditions + (("incomplete_echo", "no labels"),))
        result = incomplete_echo(
            frame.xyz,
            frame.intensity,
            frame.labels,
            label_set,
            sensor=frame.sensor,
            rng=rng,
            paint_reflectance=float(self.paint_reflectance),
            detection="sensor" if self.detection is None else self.detection,
        )
        return _apply(frame, result, (("paint_reflectance", float(self.paint_reflectance)),))


@dataclass(frozen=True, slots=True)
class CrosstalkStage:
    """False returns of an unsynchronised LiDAR nearby on a share of the beams.

    Attributes:
        name: "crosstalk".
        interfered_share: share of the beams that catch interfering pulses, [0, 1].
        severity: the preset the share came from, or None.
    """

    name: str
    interfered_share: float = 0.0
    severity: str | None = None
    version: str = SENSOR_FAULT_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> CrosstalkStage:
        return cls(name=config.stage, **config.params)

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """Interfered beams report a false return on their own ray (outcome PARTICLE)."""
        result = crosstalk(
            frame.xyz,
            frame.intensity,
            sensor=frame.sensor,
            rng=rng,
            interfered_share=float(self.interfered_share),
        )
        return _apply(frame, result, (("interfered_share", float(self.interfered_share)),))
