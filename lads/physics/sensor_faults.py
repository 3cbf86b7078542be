"""Sensor faults and scan artefacts that are not weather: dead lasers and the rolling-shutter
distortion of a sweep recorded while the vehicle moves (docs/augment.md §3).

Both return a `WeatherResult` (the shared per-point result: surviving rows, their outcome,
lost rows), so stages, the augment API and the writers treat them like weather.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.physics.ego_motion import EgoMotion, rotate_about
from lads.physics.result import Outcome, WeatherResult

FloatArray = npt.NDArray[np.float32]


def dead_channels(channels: int, share: float, rng: np.random.Generator) -> npt.NDArray[np.int64]:
    """The lasers that fail: round(share * channels) distinct channels, drawn uniformly.

    Args:
        channels: the sensor's laser count.
        share: the failed share of lasers, in [0, 1].
        rng: the frame's generator.

    Returns:
        (K,) int64 sorted channel ids in [0, channels).

    Raises:
        ConfigError: share outside [0, 1].
    """
    if not 0.0 <= share <= 1.0:
        raise ConfigError(
            f"beam_missing: lost_channel_share {share!r}; expected a share in [0, 1]."
        )
    count = int(round(share * channels))
    return np.sort(rng.choice(channels, size=count, replace=False)).astype(np.int64)


def beam_missing(
    xyz: FloatArray, intensity: FloatArray, channel: npt.NDArray[np.int64], dead: npt.ArrayLike
) -> WeatherResult:
    """Every return of a dead laser is lost; every other point is kept unchanged. A row at
    exactly zero range is no return of any laser (a dataset's placeholder) and is kept.

    Args:
        xyz: (N, 3) float32 m. intensity: (N,) float32 in the sensor's encoding.
        channel: (N,) int64 laser of each point (ring column, or nearest elevation).
        dead: channel ids that return nothing (`dead_channels`).
    """
    lost = np.isin(channel, np.asarray(dead, dtype=np.int64)) & np.any(xyz != 0, axis=1)
    rows = np.flatnonzero(~lost).astype(np.int64)
    return WeatherResult(
        xyz=np.ascontiguousarray(xyz[rows], dtype=np.float32),
        intensity=np.ascontiguousarray(intensity[rows], dtype=np.float32),
        source_index=rows,
        outcome=np.full(rows.size, Outcome.KEPT, dtype=np.uint8),
        lost_index=np.flatnonzero(lost).astype(np.int64),
        extinction_per_m=0.0,
        detection_threshold=math.nan,
    )


def sweep_time_s(
    xyz: FloatArray, *, sweep_period_s: float, seam_azimuth_deg: float, clockwise: bool = True
) -> npt.NDArray[np.float64]:
    """When in the sweep each point was measured, relative to the middle of the sweep, s.

    A spinning LiDAR measures azimuth phi at t = T * (turn from the seam to phi) / 360 deg;
    the sweep starts and ends at the seam. Returns (N,) float64 in [-T/2, T/2).
    """
    azimuth = np.degrees(np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0]))
    turn = (seam_azimuth_deg - azimuth) if clockwise else (azimuth - seam_azimuth_deg)
    return (np.mod(turn, 360.0) / 360.0 - 0.5) * sweep_period_s


def motion_distortion(
    xyz: FloatArray,
    intensity: FloatArray,
    *,
    motion: EgoMotion,
    sweep_period_s: float,
    seam_azimuth_deg: float,
) -> WeatherResult:
    """The sweep as an uncompensated sensor reports it while the vehicle moves.

    The frame is taken as the static scene seen at the middle of the sweep. A point measured
    at sweep time t (`sweep_time_s`) was seen from the sensor pose of time t: moved by v t
    and turned by R(omega t) (constant motion over the sweep). Its reported position is the
    scene point in that pose's frame, p_t = R(omega t)^T (P - v t), written as if it were
    the mid-sweep frame; points at the seam move most, by up to |v| T / 2 each way, which
    opens or overlaps the seam by |v| T.

    Args:
        xyz: (N, 3) float32 m. intensity: (N,) float32, unchanged.
        motion: the sensor's velocity (m/s) and angular velocity (deg/s) in its own frame
            (`lads.physics.ego_motion`: given, a preset's straight drive, or from poses).
        sweep_period_s: T, one revolution, s.
        seam_azimuth_deg: where the sweep starts and ends, deg.

    Returns:
        WeatherResult with every point, outcome DISPLACED where it moved (KEPT where the
        motion is zero), nothing lost.
    """
    t = sweep_time_s(xyz, sweep_period_s=sweep_period_s, seam_azimuth_deg=seam_azimuth_deg)
    shifted = xyz.astype(np.float64) - t[:, None] * np.asarray(motion.velocity_m_s)
    turned = rotate_about(shifted, motion.angular_velocity_deg_s, -t)
    out = turned.astype(np.float32)
    moved = np.any(out != xyz, axis=1)
    n = xyz.shape[0]
    return WeatherResult(
        xyz=out,
        intensity=np.ascontiguousarray(intensity, dtype=np.float32),
        source_index=np.arange(n, dtype=np.int64),
        outcome=np.where(moved, Outcome.DISPLACED, Outcome.KEPT).astype(np.uint8),
        lost_index=np.zeros(0, dtype=np.int64),
        extinction_per_m=0.0,
        detection_threshold=math.nan,
    )
