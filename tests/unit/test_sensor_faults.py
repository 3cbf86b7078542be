"""Dead lasers and the motion-distorted sweep (lads.physics.sensor_faults) against their
definitions."""

from __future__ import annotations

import numpy as np

from lads.physics import sensor_faults as faults
from lads.physics.ego_motion import straight
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
    xyz = np.ones((channel.size, 3), np.float32)
    xyz[::10] = 0.0  # one row per channel at zero range: no return of any laser, kept
    res = faults.beam_missing(xyz, np.zeros(channel.size, np.float32), channel, dead)
    assert set(channel[res.lost_index]) == set(dead.tolist())
    assert res.lost_index.size == 9 * dead.size
    kept = channel[res.source_index]
    assert not np.isin(kept[xyz[res.source_index].any(axis=1)], dead).any()
    assert np.isin(np.arange(0, channel.size, 10), res.source_index).all()
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
        motion=straight(20.0, 0.0, 0.0),
        sweep_period_s=0.1,
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
        motion=straight(10.0, 0.0, 90.0),
        sweep_period_s=0.05,
        seam_azimuth_deg=-90.0,
    )
    np.testing.assert_allclose(res.xyz[1], xyz[1], atol=1e-5)  # straight ahead
    assert abs(res.xyz[0, 1] - xyz[0, 1]) > 0.1  # the side moves along y, the forward axis
    turn = faults.motion_distortion(
        xyz,
        np.zeros(3, np.float32),
        motion=straight(0.0, 90.0, 0.0),
        sweep_period_s=0.1,
        seam_azimuth_deg=180.0,
    )
    np.testing.assert_allclose(np.linalg.norm(turn.xyz, axis=1), 10.0, rtol=1e-5)  # rotation only


def test_crosstalk_puts_false_returns_on_their_own_ray_inside_the_range_gate():
    from lads.physics.echo_faults import crosstalk
    from lads.sensors.profile import load_profile

    profile = load_profile("hdl64e")
    rng = np.random.default_rng(1)
    azimuth = rng.uniform(-180, 180, 5000)
    xyz = _ring_of_points(azimuth, 20.0)
    xyz[:, 2] = rng.uniform(-2, 2, xyz.shape[0])
    res = crosstalk(
        xyz, np.full(5000, 0.3, np.float32), sensor=profile, rng=rng, interfered_share=0.01
    )
    false = res.outcome == Outcome.PARTICLE
    assert false.sum() == 50 and res.lost_index.size == 0
    src = xyz[res.source_index[false]].astype(np.float64)
    out = res.xyz[false].astype(np.float64)
    cos = (
        np.einsum("ij,ij->i", src, out) / np.linalg.norm(src, axis=1) / np.linalg.norm(out, axis=1)
    )
    assert (cos > 1 - 1e-6).all()  # same ray, another range
    r = np.linalg.norm(out, axis=1)
    assert (r >= profile.min_range_m - 1e-3).all() and (r <= profile.max_range_m + 1e-3).all()


def test_incomplete_echo_dims_and_drops_only_clearcoat_classes_far_ones_first():
    from lads.physics.echo_faults import incomplete_echo
    from lads.sensors.profile import load_profile

    profile = load_profile("hdl64e")
    n = 4000
    range_m = np.linspace(5.0, 70.0, n)
    xyz = _ring_of_points(np.zeros(n), 1.0) * range_m[:, None].astype(np.float32)
    labels = np.where(np.arange(n) % 2 == 0, 10, 50).astype(np.uint32)  # car, building
    intensity = np.full(n, 0.3, np.float32)
    res = incomplete_echo(
        xyz,
        intensity,
        labels,
        "semantickitti",
        sensor=profile,
        rng=np.random.default_rng(0),
        paint_reflectance=0.04,
    )
    car = labels == 10
    lost = np.zeros(n, bool)
    lost[res.lost_index] = True
    assert not lost[~car].any() and lost[car].any()
    assert lost[car & (range_m > 40)].mean() > lost[car & (range_m < 15)].mean()
    kept_building = res.outcome[~car[res.source_index]]
    assert (kept_building == Outcome.KEPT).all()
    dimmed = res.intensity[res.outcome == Outcome.ATTENUATED]
    np.testing.assert_allclose(dimmed, 0.3 * 0.04 / 0.52, atol=0.006)
    same = incomplete_echo(
        xyz,
        intensity,
        labels,
        "semantickitti",
        sensor=profile,
        rng=np.random.default_rng(0),
        paint_reflectance=0.9,
    )
    assert same.lost_index.size == 0 and (same.outcome == Outcome.KEPT).all()


def _pose(x_m: float, y_m: float, yaw_deg: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    pose = np.eye(4)
    pose[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    pose[:2, 3] = [x_m, y_m]
    return pose


def test_motion_from_poses_is_the_velocity_and_turn_rate_in_the_sensor_frame():
    from lads.physics.ego_motion import from_poses

    # Heading 90 deg in the world (north), driving 12 m/s forward while turning 20 deg/s.
    times = np.array([0.0, 0.1, 0.2])
    headings = 90.0 + 20.0 * times
    r = 12.0 / np.radians(20.0)  # a left turn of radius v / omega about the origin
    poses = [_pose(r * np.sin(np.radians(h)), -r * np.cos(np.radians(h)), h) for h in headings]
    motion = from_poses(times, np.stack(poses), 1, "test")
    vx, vy, vz = motion.velocity_m_s
    assert abs(motion.speed_m_s - 12.0) < 0.05 and abs(vy) < 0.3 and vx > 11.9 and vz == 0.0
    np.testing.assert_allclose(motion.yaw_rate_deg_s, 20.0, rtol=1e-6)
    # one-sided at the end of a sequence
    end = from_poses(times[1:], np.stack(poses[1:]), 1, "test")
    assert abs(end.speed_m_s - 12.0) < 0.05
    # reversing: the velocity points backwards
    back = from_poses(times[::-1] * -1 + 0.2, np.stack(poses[::-1]), 1, "test")
    assert back.velocity_m_s[0] < -11.9


def test_motion_from_poses_refuses_one_scan_and_times_that_do_not_increase():
    import pytest

    from lads.errors import InputDataError
    from lads.physics.ego_motion import from_poses

    with pytest.raises(InputDataError, match="neighbouring scan"):
        from_poses([0.0], np.eye(4)[None], 0, "poses.txt")
    with pytest.raises(InputDataError, match="do not increase"):
        from_poses([0.1, 0.1], np.stack([np.eye(4), np.eye(4)]), 0, "poses.txt")


def test_a_general_motion_matches_the_straight_one_and_rotates_about_its_axis():
    from lads.physics.ego_motion import EgoMotion, rotate_about

    xyz = _ring_of_points(np.linspace(-179.0, 179.0, 50))
    xyz[:, 2] = 1.5
    given = faults.motion_distortion(
        xyz,
        np.zeros(50, np.float32),
        motion=EgoMotion((14.0, 0.0, 0.0), (0.0, 0.0, 10.0)),
        sweep_period_s=0.1,
        seam_azimuth_deg=180.0,
    )
    preset = faults.motion_distortion(
        xyz,
        np.zeros(50, np.float32),
        motion=straight(14.0, 10.0, 0.0),
        sweep_period_s=0.1,
        seam_azimuth_deg=180.0,
    )
    np.testing.assert_array_equal(given.xyz, preset.xyz)
    assert (given.xyz[:, 2] == xyz[:, 2]).all()  # a turn about z keeps heights
    # Rodrigues about x by 90 deg: y -> z
    turned = rotate_about(np.array([[0.0, 1.0, 0.0]]), (90.0, 0.0, 0.0), np.array([1.0]))
    np.testing.assert_allclose(turned, [[0.0, 0.0, 1.0]], atol=1e-12)


def test_crosstalk_gathers_on_targets_near_the_interferer():
    from lads.physics.echo_faults import crosstalk

    rng = np.random.default_rng(3)
    azimuth = rng.uniform(-180, 180, 20000)
    xyz = _ring_of_points(azimuth, 20.0)
    kwargs = {"sensor": "hdl64e", "interfered_share": 0.02, "interferer_range_m": 10.0}
    res = crosstalk(
        xyz, np.full(20000, 0.3, np.float32), rng=rng, interferer_azimuth_deg=90.0, **kwargs
    )
    hit_az = azimuth[res.source_index[res.outcome == Outcome.PARTICLE]]
    assert hit_az.size == 400
    towards = np.abs(((hit_az - 90.0) + 180.0) % 360.0 - 180.0) < 45.0
    away = np.abs(((hit_az + 90.0) + 180.0) % 360.0 - 180.0) < 45.0
    # the quarter of the ring facing the interferer is 10-14 m from it, the far one 26-30 m:
    # weights 1/d^2 put about half the false returns on the near quarter, few on the far one
    assert towards.mean() > 0.4 and away.mean() < 0.1
    # a drawn azimuth differs per generator, and the same generator repeats itself
    a = crosstalk(xyz, np.full(20000, 0.3, np.float32), rng=np.random.default_rng(5), **kwargs)
    b = crosstalk(xyz, np.full(20000, 0.3, np.float32), rng=np.random.default_rng(5), **kwargs)
    np.testing.assert_array_equal(a.xyz, b.xyz)
