"""A frame is refused as another sensor's only when its beam geometry says so clearly."""

from __future__ import annotations

import numpy as np
import pytest

from lads.errors import InvalidPointsError
from lads.sensors.conformity import MIN_JUDGED_POINTS, NEAR_FIELD_M, check_scan_of
from lads.sensors.profile import load_profile
from tests.conftest import street_frame

HDL32, HDL64 = load_profile("hdl32e"), load_profile("hdl64e")


def _ego_returns(n: int, rng: np.random.Generator) -> np.ndarray:
    """Returns of the vehicle's own body: within 2.3 m, apparent elevations -59..-20 deg."""
    az, el = rng.uniform(-np.pi, np.pi, n), np.radians(rng.uniform(-59, -20, n))
    r = rng.uniform(0.3, 2.3, n)
    return np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)


def test_a_scan_with_a_third_of_its_points_on_the_ego_body_passes():
    rng = np.random.default_rng(0)
    xyz, _ = street_frame(HDL32, azimuths=360)
    frame = np.concatenate([xyz, _ego_returns(len(xyz) // 2, rng), np.zeros((50, 3))])
    ring = np.concatenate([HDL32.channel_of(xyz), rng.integers(0, 32, len(frame) - len(xyz))])
    check_scan_of(frame, HDL32)  # no ring column
    check_scan_of(frame, HDL32, ring=ring)


def test_far_returns_outside_the_field_of_view_mean_another_sensor():
    xyz, _ = street_frame(HDL32, azimuths=360)  # up to +10.7 deg
    far = np.linalg.norm(xyz, axis=1) > NEAR_FIELD_M
    with pytest.raises(InvalidPointsError, match=r"returns beyond 3 m .* 'hdl64e'"):
        check_scan_of(xyz[far], HDL64, where="f")  # HDL-64E sees only up to +2 deg


def test_ring_ids_beyond_the_profile_channels_are_refused():
    xyz, _ = street_frame(HDL64, azimuths=180)
    with pytest.raises(InvalidPointsError, match="not channels 0..31"):
        check_scan_of(xyz, HDL32, ring=HDL64.channel_of(xyz))


def test_rings_far_from_their_channel_elevation_are_refused():
    xyz, _ = street_frame(HDL32, azimuths=360)
    ring = HDL32.channel_of(xyz)
    check_scan_of(xyz, HDL32, ring=ring)
    with pytest.raises(InvalidPointsError, match="rings have a median elevation"):
        check_scan_of(xyz, HDL32, ring=(31 - ring))  # ring order reversed: another layout


def test_too_few_far_returns_are_not_judged():
    rng = np.random.default_rng(1)
    tiny = rng.normal(0, 30, (MIN_JUDGED_POINTS - 1, 3))
    tiny[:, 2] = 50.0  # all far above any field of view
    check_scan_of(tiny, HDL64)


def test_the_compiled_field_of_view_count_is_the_arctangent_rule():
    from lads.sensors.conformity import FOV_MARGIN_DEG, _fov_counts, _tan_deg

    rng = np.random.default_rng(2)
    xyz = rng.normal(0, 20, (20000, 3)).astype(np.float32)
    xyz[:10] = np.nan  # never judged
    low, high = HDL64.vertical_fov_deg
    for step in (1, 3):
        p = xyz[::step].astype(np.float64)
        with np.errstate(invalid="ignore"):
            far = np.linalg.norm(p, axis=1) > NEAR_FIELD_M
        elevation = np.degrees(np.arctan2(p[far, 2], np.hypot(p[far, 0], p[far, 1])))
        outside = (elevation < low - FOV_MARGIN_DEG) | (elevation > high + FOV_MARGIN_DEG)
        got = _fov_counts(
            xyz, step, NEAR_FIELD_M, _tan_deg(low - FOV_MARGIN_DEG), _tan_deg(high + FOV_MARGIN_DEG)
        )
        assert got == (int(far.sum()), int(outside.sum()))
    assert _tan_deg(95.0) == np.inf and _tan_deg(-90.0) == -np.inf
