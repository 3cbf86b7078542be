"""Sensor-fault stages: dead lasers, a motion-distorted sweep (`lads.physics.sensor_faults`),
returns lost to dark glossy paint and another LiDAR's false returns (`lads.physics.echo_faults`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lads.config import StageConfig
from lads.errors import ConfigError
from lads.frame import RING_COLUMN, Frame
from lads.physics import sensor_faults as faults
from lads.physics.echo_faults import INTERFERER_RANGE_M, crosstalk, incomplete_echo
from lads.physics.ego_motion import EgoMotion, from_poses, straight
from lads.physics.materials import class_ids, class_roles
from lads.physics.projection import MIN_RANGE_M, channels_of, range_m
from lads.physics.result import Outcome, WeatherResult
from lads.readers import label_set_for
from lads.readers.poses import PoseTrack
from lads.sensors.profile import SensorProfile, load_profile

# Bump when the output bytes change for the same input and seed.
SENSOR_FAULT_STAGE_VERSION = "3"


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


def _ego_body(frame: Frame) -> np.ndarray:
    """(M,) bool: returns of the recording vehicle's own body (classes materials.yaml marks
    `ego`); all False without labels."""
    label_set = label_set_for(frame.item.dataset)
    if frame.labels is None or label_set is None:
        return np.zeros(frame.points.shape[0], dtype=bool)
    ego = sorted(class_roles(label_set).ego)
    return (
        np.isin(class_ids(frame.labels, label_set), ego)
        if ego
        else np.zeros(len(frame.labels), bool)
    )


@dataclass(frozen=True, slots=True)
class BeamMissingStage:
    """Whole lasers fail: every return of `lost_channel_share` of the channels is lost.

    Attributes:
        name: "beam_missing".
        lost_channel_share: share of the sensor's lasers that fail, in [0, 1] (not needed
            with `channels`).
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
    """The sweep as an uncompensated sensor reports it while moving (docs/augment.md §3).

    The motion is one of: `speed_m_s` (with `yaw_rate_deg_s`) along the profile's forward
    azimuth, as the severity presets give it; `velocity_m_s` and `angular_velocity_deg_s`
    in the sensor frame; or `ego_motion: poses`, the motion recorded by the sequence's poses
    (a build reads them: `needs_track`).

    Attributes:
        name: "motion_distortion".
        speed_m_s: forward speed, m/s.
        yaw_rate_deg_s: turn rate about z with `speed_m_s`, deg/s (positive: to the left).
        velocity_m_s: (3,) sensor velocity in its own frame, m/s.
        angular_velocity_deg_s: (3,) with `velocity_m_s`, deg/s.
        ego_motion: "poses", or None for a motion given by the parameters above.
        sweep_period_s: one revolution, s; None = the sensor profile's.
        seam_azimuth_deg: where the sweep starts and ends, deg; None = behind the vehicle
            (the profile's forward azimuth + 180).
        severity: the preset the speed came from, or None.
    """

    name: str
    speed_m_s: float | None = None
    yaw_rate_deg_s: float | None = None
    velocity_m_s: tuple[float, float, float] | None = None
    angular_velocity_deg_s: tuple[float, float, float] | None = None
    ego_motion: str | None = None
    sweep_period_s: float | None = None
    seam_azimuth_deg: float | None = None
    severity: str | None = None
    version: str = SENSOR_FAULT_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> MotionDistortionStage:
        """Raises ConfigError unless exactly one motion is given."""
        params = dict(config.params)
        for key in ("velocity_m_s", "angular_velocity_deg_s"):
            if params.get(key) is not None:
                params[key] = tuple(float(v) for v in params[key])
        given = [
            k for k in ("speed_m_s", "velocity_m_s", "ego_motion") if params.get(k) is not None
        ]
        pairs = (("yaw_rate_deg_s", "speed_m_s"), ("angular_velocity_deg_s", "velocity_m_s"))
        stray = [k for k, needs in pairs if params.get(k) is not None and needs not in given]
        if len(given) != 1 or stray:
            raise ConfigError(
                f"motion_distortion: motion given by {given or 'nothing'}"
                f"{f', and {stray} without their speed or velocity' if stray else ''}; give one "
                "of speed_m_s (or severity), velocity_m_s, or ego_motion: poses."
            )
        return cls(name=config.stage, **params)

    @property
    def needs_track(self) -> bool:
        """True when a build must hand the stage the frame's poses (`call_track`)."""
        return self.ego_motion is not None

    def timing(self, profile: SensorProfile) -> tuple[float, float | None, float]:
        """(sweep period s, forward azimuth deg or None, seam azimuth deg) for this sensor.

        Raises:
            ConfigError: the profile lacks a value the stage needs and was not given.
        """
        period = self.sweep_period_s if self.sweep_period_s is not None else profile.sweep_period_s
        forward = profile.forward_azimuth_deg
        seam = self.seam_azimuth_deg
        if seam is None and forward is not None:
            seam = forward + 180.0
        if period is None or seam is None:
            raise ConfigError(
                f"motion_distortion: sensor profile '{profile.name}' has no sweep_period_s or "
                "forward_azimuth_deg; add them to the profile (see lads/sensors/hdl64e.yaml) "
                "or pass sweep_period_s and seam_azimuth_deg."
            )
        return float(period), forward, float(seam)

    def given_motion(self, forward_azimuth_deg: float | None) -> EgoMotion:
        """The motion the parameters give (not `ego_motion: poses`)."""
        if self.velocity_m_s is not None:
            return EgoMotion(self.velocity_m_s, self.angular_velocity_deg_s or (0.0, 0.0, 0.0))
        if self.ego_motion is not None:
            raise ConfigError(
                "motion_distortion: ego_motion: poses needs the sequence's poses, which a build "
                "of a source with poses hands the stage; on single clouds give velocity_m_s "
                "(lads.augment.ego_motion_from_poses makes it from your poses)."
            )
        if forward_azimuth_deg is None:
            raise ConfigError(
                "motion_distortion: speed_m_s needs the profile's forward_azimuth_deg; give "
                "velocity_m_s in the sensor frame instead."
            )
        speed, yaw = float(self.speed_m_s or 0.0), float(self.yaw_rate_deg_s or 0.0)
        return straight(speed, yaw, forward_azimuth_deg)

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """Every point moved to where the moving sensor reported it; zero-range rows (no
        return) stay where they are. Uses no randomness."""
        profile = load_profile(frame.sensor)
        return self._distort(frame, self.given_motion(self.timing(profile)[1]), profile)

    def call_track(self, frame: Frame, track: PoseTrack, rng: np.random.Generator) -> Frame:
        """As `__call__`, with the motion of `track` (the reader's poses around the frame)."""
        motion = from_poses(track.times_s, track.poses, track.centre, track.where)
        return self._distort(frame, motion, load_profile(frame.sensor))

    def _distort(self, frame: Frame, motion: EgoMotion, profile: SensorProfile) -> Frame:
        period, _, seam = self.timing(profile)
        result = faults.motion_distortion(
            frame.xyz, frame.intensity, motion=motion, sweep_period_s=period, seam_azimuth_deg=seam
        )
        # No return, or a return of the vehicle's own body, which moves with the sensor.
        still = (range_m(frame.xyz) <= MIN_RANGE_M) | _ego_body(frame)
        if still.any():
            result.xyz[still] = frame.xyz[still]
            result.outcome[still] = Outcome.KEPT
        vx, vy, vz = motion.velocity_m_s
        conditions = (
            ("speed_m_s", round(motion.speed_m_s, 6)),
            ("velocity_m_s", f"{vx:.6g} {vy:.6g} {vz:.6g}"),
            ("yaw_rate_deg_s", round(motion.yaw_rate_deg_s, 6)),
            ("sweep_period_s", period),
        )
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
        interferer_range_m: distance of the interfering LiDAR, m.
        interferer_azimuth_deg: its azimuth, deg; None draws it per frame.
        severity: the preset the share came from, or None.
    """

    name: str
    interfered_share: float = 0.0
    interferer_range_m: float = INTERFERER_RANGE_M
    interferer_azimuth_deg: float | None = None
    severity: str | None = None
    version: str = SENSOR_FAULT_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> CrosstalkStage:
        # an explicit null means the default (distance) or a drawn azimuth
        return cls(name=config.stage, **{k: v for k, v in config.params.items() if v is not None})

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        """Interfered beams report a false return on their own ray (outcome PARTICLE)."""
        result = crosstalk(
            frame.xyz,
            frame.intensity,
            sensor=frame.sensor,
            rng=rng,
            interfered_share=float(self.interfered_share),
            interferer_range_m=float(self.interferer_range_m),
            interferer_azimuth_deg=self.interferer_azimuth_deg,
        )
        conditions = (
            ("interfered_share", float(self.interfered_share)),
            ("interferer_range_m", float(self.interferer_range_m)),
        )
        return _apply(frame, result, conditions)
