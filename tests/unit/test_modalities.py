"""Per-point modalities: lads/physics/modalities.py (docs/physics.md §10.1, §10.3)."""

from __future__ import annotations

import numpy as np
import pytest

from lads.errors import ConfigError, InputDataError, InvalidPointsError
from lads.physics.modalities import (
    IncidenceSource,
    RangeImage,
    channels,
    compute_modalities,
    incidence,
    incidence_cos,
    physics_intensity,
    project,
    range_m,
)
from lads.sensors.profile import load_profile
from lads.synth import synth_frame

HDL64 = load_profile("hdl64e")
SENSOR_HEIGHT_M = 1.73


def planar_street(wall_x_m: float | None = 8.0, max_range_m: float = 60.0):
    """Every HDL-64E beam cast at a flat ground (z = -1.73 m) and a wall facing the sensor.

    Returns xyz (N, 3), the beam's channel (N,) and the analytic incidence cosine (N,):
    |d_z| on the ground, |d_x| on the wall x = wall_x_m (none if wall_x_m is None).
    """
    el = np.radians(np.asarray(HDL64.elevation_deg))[:, None]
    width = HDL64.range_image_width
    az = ((np.arange(width) + 0.5) * 2 * np.pi / width - np.pi)[None, :]
    el, az = np.broadcast_arrays(el, az)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    d = d.reshape(-1, 3)
    ring = np.broadcast_to(np.arange(HDL64.channels)[:, None], el.shape).reshape(-1)
    with np.errstate(divide="ignore"):
        t_ground = np.where(d[:, 2] < 0, -SENSOR_HEIGHT_M / d[:, 2], np.inf)
        t_wall = np.full(len(d), np.inf)
        if wall_x_m is not None:
            t_wall = np.where(d[:, 0] > 0, wall_x_m / d[:, 0], np.inf)
    t = np.minimum(t_ground, t_wall)
    cos = np.where(t_ground < t_wall, np.abs(d[:, 2]), np.abs(d[:, 0]))
    keep = t < max_range_m
    return d[keep] * t[keep, None], ring[keep], cos[keep]


# --- range and channels ---------------------------------------------------------------


def test_range_is_the_euclidean_norm_as_float32():
    out = range_m(np.array([[3.0, 4.0, 0.0], [0.0, 0.0, -2.0]]))
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, [5.0, 2.0])


def test_channels_take_the_ring_column_when_given():
    xyz, ring, _ = planar_street()
    np.testing.assert_array_equal(channels(xyz, HDL64, ring=ring.astype(np.float32)), ring)
    np.testing.assert_array_equal(channels(xyz, HDL64), HDL64.channel_of(xyz))


@pytest.mark.parametrize("ring", [[0, 64], [-1, 3], [0.5, 3], [np.nan, 1], [0]])
def test_bad_rings_raise(ring):
    xyz = np.array([[5.0, 0, 0], [0, 5.0, 0]])
    with pytest.raises(InvalidPointsError, match="ring"):
        channels(xyz, HDL64, ring=np.array(ring))


# --- projection -----------------------------------------------------------------------


def test_projection_rows_are_channels_top_down_and_columns_follow_azimuth():
    width = HDL64.range_image_width
    xyz = np.array([[10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [-10.0, 0.0, 0.0], [-10.0, -0.0, 0.0]])
    image = project(xyz, HDL64, channel=np.array([0, 63, 5, 5]))
    assert image.index.shape == (64, width) and image.xyz.shape == (64, width, 3)
    np.testing.assert_array_equal(image.row, [63, 0, 58, 58])
    # u = 0.5 (-atan2(y, x) / pi + 1) W: forward -> W/2, left -> W/4, behind -> 0 (u = W wraps)
    np.testing.assert_array_equal(image.col, [width // 2, width // 4, 0, 0])
    assert image.mask.sum() == 3 and image.index[63, width // 2] == 0
    assert image.index[58, 0] == 2  # equal ranges: the lower index owns the pixel
    assert np.all(image.range_m[~image.mask] == 0) and np.all(image.index[~image.mask] == -1)


@pytest.mark.parametrize("near_first", [True, False])
def test_projection_nearest_point_wins_its_pixel(near_first):
    near, far = [4.0, 0.01, 0.0], [20.0, 0.05, 0.0]
    xyz = np.array([near, far] if near_first else [far, near])
    image = project(xyz, HDL64, channel=np.array([10, 10]))
    owner = image.index[image.row[0], image.col[0]]
    assert image.col[0] == image.col[1] and image.mask.sum() == 1
    assert owner == (0 if near_first else 1)
    assert image.range_m[image.row[0], image.col[0]] == pytest.approx(4.0, rel=1e-5)


def test_projection_ties_go_to_the_lower_index():
    xyz = np.array([[5.0, 0.0, 0.0]] * 3)
    image = project(xyz, HDL64, channel=np.zeros(3, dtype=int))
    assert image.index[image.row[0], image.col[0]] == 0


def test_projection_keeps_points_outside_the_nominal_fov():
    steep = np.array([[1.0, 0.0, -5.0], [1.0, 0.0, 5.0]])  # -79 and +79 degrees
    image = project(steep, HDL64)
    np.testing.assert_array_equal(image.row, [63, 0])
    assert image.mask.sum() == 2


def test_projection_rejects_a_width_below_3():
    with pytest.raises(ConfigError):
        project(np.array([[1.0, 0, 0]]), HDL64, width=2)


# --- incidence ------------------------------------------------------------------------


def test_incidence_matches_the_analytic_cosine_on_a_wall_and_ground():
    xyz, ring, truth = planar_street(wall_x_m=8.0)
    inc = incidence(xyz, HDL64, channel=ring)
    err = np.abs(inc.cos - truth)
    # Within ~0.35 m of the crease, where ground meets wall, normals blend both planes.
    crease_m = np.hypot(xyz[:, 0] - 8.0, xyz[:, 2] + SENSOR_HEIGHT_M)
    away = (crease_m > 0.5) & (inc.source == IncidenceSource.IMAGE)
    assert np.mean(inc.source == IncidenceSource.IMAGE) > 0.95
    assert err[away].max() < 0.05
    assert np.mean(err < 0.05) > 0.97


def test_incidence_on_ground_alone_uses_one_sided_differences_at_the_lowest_ring():
    xyz, ring, truth = planar_street(wall_x_m=None, max_range_m=30.0)
    inc = incidence(xyz, HDL64, channel=ring)
    assert np.all(inc.source[ring == 0] == IncidenceSource.IMAGE)
    # The last ring before the 30 m cut has only a neighbour 13 % nearer: no normal there.
    inner = np.linalg.norm(xyz, axis=1) < 25.0
    np.testing.assert_allclose(inc.cos[inner], truth[inner], atol=0.05)


def test_every_point_gets_a_finite_cos_in_0_1():
    scan = synth_frame(HDL64, frames=1, seed=0, index=0)
    xyz = np.concatenate([scan.xyz, scan.xyz[:500], [[0.5, 0.0, 30.0]]])  # duplicates, a loner
    inc = incidence(xyz, HDL64)
    assert inc.cos.shape == (len(xyz),) and inc.cos.dtype == np.float32
    assert np.all(np.isfinite(inc.cos)) and np.all((inc.cos >= 0) & (inc.cos <= 1))
    assert inc.source[-1] == IncidenceSource.MEDIAN
    assert inc.cos[-1] == pytest.approx(np.median(inc.cos[inc.source != IncidenceSource.MEDIAN]))


def test_a_lone_point_falls_back_to_0_5():
    assert incidence_cos(np.array([[10.0, 0.0, 0.0]]), HDL64)[0] == pytest.approx(0.5)


def test_points_sharing_a_pixel_use_their_own_ray_and_are_not_dropped():
    xyz, ring, truth = planar_street(wall_x_m=8.0)
    image = project(xyz, HDL64, channel=ring, width=HDL64.range_image_width // 2)
    assert image.mask.sum() < len(xyz)  # two beams per pixel
    inc = incidence(xyz, HDL64, image=image)
    assert np.mean(np.abs(inc.cos - truth) < 0.05) > 0.95


def test_a_prebuilt_image_gives_the_same_result():
    xyz, ring, _ = planar_street()
    image = project(xyz, HDL64, channel=ring)
    np.testing.assert_array_equal(
        incidence_cos(xyz, HDL64, image=image), incidence_cos(xyz, HDL64, channel=ring)
    )
    with pytest.raises(InvalidPointsError, match="project the same cloud"):
        incidence_cos(xyz[:-1], HDL64, image=image)
    with pytest.raises(ConfigError):
        incidence_cos(xyz, HDL64, image=image, channel=ring)


def test_a_wall_point_behind_a_pole_takes_the_walls_normal_from_its_neighbours():
    xyz, ring, truth = planar_street(wall_x_m=8.0)
    # A pole 3 m in front of the wall owns one column of pixels; the wall points behind it
    # lose their pixel (another surface) and must take the wall's normal, not the pole's.
    on_wall = np.abs(xyz[:, 0] - 8.0) < 1e-6
    behind = np.flatnonzero(on_wall & (np.abs(xyz[:, 1]) < 0.02) & (np.abs(xyz[:, 2]) < 1.0))
    assert behind.size >= 5
    pole = xyz[behind] * (5.0 / 8.0)
    inc = incidence(np.concatenate([xyz, pole]), HDL64, channel=np.r_[ring, ring[behind]])
    assert np.all(inc.source[behind] == IncidenceSource.NEIGHBOURS)
    np.testing.assert_allclose(inc.cos[behind], truth[behind], atol=0.05)


# --- physics intensity ----------------------------------------------------------------


def test_physics_intensity_is_rho_cos_over_r_to_the_n_times_two_way_extinction():
    rho, cos, rng = np.array([0.5, 1.0]), np.array([0.8, 0.5]), np.array([10.0, 40.0])
    np.testing.assert_allclose(physics_intensity(rho, cos, rng), rho * cos / rng, rtol=1e-6)
    np.testing.assert_allclose(
        physics_intensity(rho, cos, rng, range_exponent=2.0, extinction_per_m=0.01),
        rho * cos / rng**2 * np.exp(-0.02 * rng),
        rtol=1e-6,
    )
    out = physics_intensity(rho, cos, rng, range_exponent=0.0)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, rho * cos, rtol=1e-6)


def test_physics_intensity_clamps_ranges_below_1_mm():
    out = physics_intensity(np.array([0.5]), np.array([1.0]), np.array([1e-5]))
    assert out[0] == pytest.approx(0.5 / 1e-3)


@pytest.mark.parametrize(
    ("rho", "cos", "rng"),
    [
        ([-0.1], [0.5], [1.0]),
        ([0.5], [1.5], [1.0]),
        ([0.5], [0.5], [np.nan]),
        ([0.5], [0.5], [-1.0]),
        ([0.5, 0.5], [0.5], [1.0]),
    ],
)
def test_physics_intensity_rejects_bad_inputs(rho, cos, rng):
    with pytest.raises(InvalidPointsError):
        physics_intensity(np.array(rho), np.array(cos), np.array(rng))


@pytest.mark.parametrize("kwargs", [{"range_exponent": -1.0}, {"extinction_per_m": np.inf}])
def test_physics_intensity_rejects_bad_parameters(kwargs):
    with pytest.raises(ConfigError):
        physics_intensity(np.array([0.5]), np.array([0.5]), np.array([1.0]), **kwargs)


# --- compute_modalities and bad input -------------------------------------------------


def test_compute_modalities_combines_the_parts():
    scan = synth_frame(HDL64, frames=1, seed=0, index=0)
    mods = compute_modalities(scan.xyz, scan.labels, "semantickitti", HDL64, ring=scan.ring)
    np.testing.assert_array_equal(mods.channel, scan.ring)
    np.testing.assert_allclose(mods.range_m, range_m(scan.xyz))
    np.testing.assert_array_equal(
        mods.cos_incidence, incidence_cos(scan.xyz, HDL64, channel=scan.ring)
    )
    expected = mods.reflectance * mods.cos_incidence / mods.range_m
    np.testing.assert_allclose(mods.physics_intensity, expected, rtol=1e-5)
    road = scan.labels == 40
    assert np.all(mods.reflectance[road] == np.float32(0.10))


def test_empty_frames_give_empty_arrays():
    mods = compute_modalities(np.zeros((0, 3)), np.zeros(0, np.uint32), "semantickitti", HDL64)
    dtypes = {"range_m": np.float32, "channel": np.int64, "cos_incidence": np.float32}
    for name, dtype in {
        **dtypes,
        "reflectance": np.float32,
        "physics_intensity": np.float32,
    }.items():
        arr = getattr(mods, name)
        assert arr.shape == (0,) and arr.dtype == dtype
    assert isinstance(project(np.zeros((0, 3)), HDL64), RangeImage)


@pytest.mark.parametrize(
    ("xyz", "message"),
    [
        (np.array([[1.0, 2.0, np.nan], [1.0, np.inf, 0.0], [1.0, 0, 0]]), "2 of 3 points have NaN"),
        (np.array([[0.0, 0.0, 0.0], [1.0, 0, 0]]), "1 of 2 points lie at zero range"),
        (np.ones((4, 4)), r"expected an \(N, 3\)"),
        (np.ones(3), r"expected an \(N, 3\)"),
    ],
)
def test_bad_points_raise_naming_the_problem_and_count(xyz, message):
    labels = np.zeros(len(xyz), np.uint32)
    for call in (
        lambda: compute_modalities(xyz, labels, "semantickitti", HDL64),
        lambda: project(xyz, HDL64),
        lambda: incidence_cos(xyz, HDL64),
    ):
        with pytest.raises(InvalidPointsError, match=message):
            call()


def test_labels_must_match_the_points():
    with pytest.raises(InvalidPointsError, match="one per point"):
        compute_modalities(np.ones((3, 3)), np.zeros(2, np.uint32), "semantickitti", HDL64)
    with pytest.raises(InputDataError):
        compute_modalities(np.ones((1, 3)), np.array([-3]), "semantickitti", HDL64)
    with pytest.raises(ConfigError):
        compute_modalities(np.ones((1, 3)), np.array([3]), "kitti", HDL64)


def test_the_compiled_organise_is_the_numpy_form_bit_for_bit():
    from lads.physics.image_kernels import pixel_owners
    from lads.physics.projection import organise

    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(5000, 3)) * [20.0, 20.0, 2.0]
    xyz[:50] = xyz[50:100] * 1.5  # the same directions farther: pixels with two points
    xyz[100] = [-5.0, -0.0, 1.0]  # azimuth -pi: u == W, column 0
    xyz[101] = [-5.0, 0.0, 1.0]  # azimuth +pi
    r = np.sqrt((xyz**2).sum(1))
    chan = rng.integers(0, 8, len(xyz))
    for width in (16, 2048):
        got = organise(xyz, r, chan, 8, width)
        row = 7 - chan
        u = 0.5 * (-np.arctan2(xyz[:, 1], xyz[:, 0]) / np.pi + 1.0) * width
        col = np.floor(u).astype(np.int64) % width
        pixel = row * width + col
        index = pixel_owners(pixel, r, 8 * width)
        owners = index[index >= 0]
        range_img = np.zeros(8 * width, dtype=np.float32)
        range_img[pixel[owners]] = r[owners]
        xyz_img = np.zeros((8 * width, 3), dtype=np.float32)
        xyz_img[pixel[owners]] = xyz[owners]
        assert np.array_equal(got.row, row) and np.array_equal(got.col, col)
        assert np.array_equal(got.index.ravel(), index)
        assert np.array_equal(got.range_m.ravel().view(np.int32), range_img.view(np.int32))
        assert np.array_equal(got.xyz.reshape(-1, 3).view(np.int32), xyz_img.view(np.int32))
        assert got.col[100] == 0 and got.col[101] == 0


def test_nearest_channels_are_numpys_searchsorted_positions():
    from lads.sensors.lookup import left_positions

    rng = np.random.default_rng(4)
    table = np.sort(rng.normal(size=63))
    values = np.r_[rng.normal(size=10000) * 2, table, np.nextafter(table, 9), np.nan, np.inf]
    assert np.array_equal(left_positions(table, values), np.searchsorted(table, values))
    assert left_positions(table, values[:7000].reshape(-1, 7)).shape == (1000, 7)


@pytest.mark.parametrize("name", ["hdl64e", "hdl32e"])
def test_nearest_channel_by_slope_is_numpys_angle(name):
    """The compiled slope test gives the channel numpy's degrees(arctan2) gives, also a
    hair off a midpoint's direction (where the guard hands the point to its angle), at the
    origin and straight up or down. Exactly on a midpoint the angle in the last bit decides
    (numpy's own varies there with the arrays' memory layout), so either neighbouring
    channel is right, the same one every time."""
    from lads.sensors.lookup import elevation_positions, left_positions

    def numpy_channels(xyz):
        elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
        return left_positions(mids, elevation)

    table = np.asarray(load_profile(name).elevation_deg, dtype=np.float64)
    mids = 0.5 * (table[1:] + table[:-1])
    rng = np.random.default_rng(5)
    az = rng.uniform(0.0, 2.0 * np.pi, mids.size * 40)
    el = np.radians(np.repeat(mids, 40))
    r = rng.uniform(0.5, 100.0, az.size)
    on = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    near = on.copy()
    near[:, 2] *= 1.0 + rng.choice([-1e-11, 1e-11], r.size)
    special = np.array(
        [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -2.0], [5.0, 0.0, 0.0], [np.nan, 1.0, 1.0]]
    )
    scan = rng.normal(size=(20000, 3)) * [30.0, 30.0, 4.0]
    xyz = np.concatenate([scan, near, special])
    assert np.array_equal(elevation_positions(xyz, mids), numpy_channels(xyz))
    assert np.array_equal(load_profile(name).channel_of(xyz), numpy_channels(xyz))
    below = np.repeat(np.arange(mids.size), 40)  # the midpoints below each point's own
    got = elevation_positions(on, mids)
    assert np.isin(got - below, [0, 1]).all()
    assert np.array_equal(elevation_positions(on[::-1].copy(), mids), got[::-1])
