"""Dead lasers and the motion-distorted sweep (lads.physics.sensor_faults) against their
definitions."""

from __future__ import annotations

import numpy as np

from lads.physics import sensor_faults as faults
from lads.physics.result import Outcome


def _ring_of_points(azimuth_deg: np.ndarray, range_m: float = 10.0) -> np.ndarray:
    a = np.radians(azimuth_deg)
    return np.column_stack([range_m * np.cos(a), range_m * np.sin(a), np.zeros_like(a)]).astype(
        np.float32
    )


def test_dead_channels_are_distinct_and_their_returns_all_lost():
    rng = np.random.default_rng(0)
    dead = faults.dead_channels(64, 0.25, rng)
    assert dead.size == 16 and np.unique(dead).size == 16
    channel = np.repeat(np.arange(64), 10)
    xyz = np.zeros((channel.size, 3), np.float32)
    res = faults.beam_missing(xyz, np.zeros(channel.size, np.float32), channel, dead)
    assert set(channel[res.lost_index]) == set(dead.tolist())
    assert not np.isin(channel[res.source_index], dead).any()
    assert (res.outcome == Outcome.KEPT).all()


def test_sweep_time_is_zero_ahead_and_half_a_period_at_the_seam():
    xyz = _ring_of_points(np.array([0.0, 90.0, 179.9, -179.9]))
    t = faults.sweep_time_s(xyz, sweep_period_s=0.1, seam_azimuth_deg=180.0)
    np.testing.assert_allclose(t[0], 0.0, atol=1e-9)
    # clockwise: the left side (90 deg) is seen a quarter turn before the front
    np.testing.assert_allclose(t[1], -0.025, atol=1e-6)
    assert t[2] < -0.0499 and t[3] > 0.0499


def test_the_seam_opens_by_speed_times_period():
    xyz = _ring_of_points(np.array([0.0, 179.99, -179.99]))
    res = faults.motion_distortion(
        xyz,
        np.zeros(3, np.float32),
        speed_m_s=20.0,
        yaw_rate_deg_s=0.0,
        sweep_period_s=0.1,
        forward_azimuth_deg=0.0,
        seam_azimuth_deg=180.0,
    )
    np.testing.assert_allclose(res.xyz[0], xyz[0], atol=1e-5)  # ahead: measured mid-sweep
    gap = res.xyz[1, 0] - res.xyz[2, 0]
    np.testing.assert_allclose(abs(gap), 20.0 * 0.1, rtol=1e-3)
    assert res.outcome[1] == Outcome.DISPLACED and res.lost_index.size == 0


def test_forward_axis_and_yaw_follow_the_profile_convention():
    xyz = _ring_of_points(np.array([0.0, 90.0, 180.0 - 1e-3]))
    # nuScenes-like: y forward; the seam behind is at -90 deg
    res = faults.motion_distortion(
        xyz,
        np.zeros(3, np.float32),
        speed_m_s=10.0,
        yaw_rate_deg_s=0.0,
        sweep_period_s=0.05,
        forward_azimuth_deg=90.0,
        seam_azimuth_deg=-90.0,
    )
    np.testing.assert_allclose(res.xyz[1], xyz[1], atol=1e-5)  # straight ahead
    assert abs(res.xyz[0, 1] - xyz[0, 1]) > 0.1  # the side moves along y, the forward axis
    turn = faults.motion_distortion(
        xyz,
        np.zeros(3, np.float32),
        speed_m_s=0.0,
        yaw_rate_deg_s=90.0,
        sweep_period_s=0.1,
        forward_azimuth_deg=0.0,
        seam_azimuth_deg=180.0,
    )
    np.testing.assert_allclose(np.linalg.norm(turn.xyz, axis=1), 10.0, rtol=1e-5)  # rotation only
