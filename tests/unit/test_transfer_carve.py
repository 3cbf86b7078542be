"""Free-space carving: a hit in front of what every centre beam around it measured takes no
part, the beam takes the surface behind; unknown space (no return) and surfaces the centre
scan saw are kept; the per-beam bound equals testing each hit on its own."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lads.sensors.profile import load_profile
from lads.transfer.carve import (
    CARVE_NOISE_SIGMAS,
    CARVE_SHARE,
    FreeSpace,
    carve_floor,
    free_space,
    nearest_hits,
)
from lads.transfer.cast import cast_parts

HDL64 = load_profile("hdl64e")
EL = np.sort(np.radians(np.asarray(HDL64.elevation_deg, dtype=np.float64)))
W = HDL64.range_image_width


def _beam_points(range_m: float, rows: slice, columns: slice) -> np.ndarray:
    """Points at `range_m` along the source's own beams (row, bin centre)."""
    az = (np.arange(W) + 0.5) * 2 * math.pi / W - math.pi
    e, a = np.meshgrid(EL[rows], az[columns], indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    return d * range_m


def _disks(points: np.ndarray, radius_m: float) -> dict[str, np.ndarray]:
    """Disks facing the origin at `points`, as the cast reads them."""
    n = len(points)
    normal = -points / np.linalg.norm(points, axis=1, keepdims=True)
    a = np.cross(normal, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(normal, a)
    return {
        "centre": points,
        "normal": normal,
        "axis_a": a * radius_m,
        "axis_b": b * radius_m,
        "radius_m": np.full(n, 2 * radius_m),
        "albedo": np.full(n, 0.3),
        "weight": np.ones(n),
        "retro": np.zeros(n, bool),
    }


def test_a_disk_in_space_the_centre_scan_saw_through_is_carved_and_the_wall_wins():
    # The centre scan saw a wall 10 m ahead on rows 20-44 around azimuth 0; above row 44
    # it saw nothing (sky). Another scan lends a 0.5 m disk 5 m ahead in front of the wall,
    # and another one 5 m ahead where the centre scan saw the sky.
    cols = slice(W // 2 - 40, W // 2 + 40)
    wall = _beam_points(10.0, slice(20, 45), cols)
    low = np.array([[5.0, 0.0, 5.0 * math.tan(EL[30])]])
    high = np.array([[5.0, 0.0, 5.0 * math.tan(EL[55])]])
    parts = [_disks(wall, 0.2), _disks(np.vstack([low, high]), 0.5)]
    kept = [np.arange(len(wall)), np.arange(2)]
    poses = [np.eye(4), np.eye(4)]
    args = (parts, kept, poses, EL, W)
    plain = cast_parts(*args, azimuth_offset_rad=-math.pi)
    free = free_space(wall, HDL64, np.eye(4))
    carved = cast_parts(*args, azimuth_offset_rad=-math.pi, free=free)
    k_low, k_high, j = 30, 55, W // 2
    assert plain.range_m[k_low, j] == pytest.approx(np.linalg.norm(low), rel=1e-2)
    assert carved.range_m[k_low, j] == pytest.approx(10.0, rel=1e-2)
    assert carved.owner[k_low, j] < len(wall)  # a wall disk owns the beam now
    assert plain.range_m[k_high, j] == carved.range_m[k_high, j]  # the sky: unknown, kept
    # Beams the disk never touched are the same bytes with or without carving.
    untouched = ~(plain.range_m < 6.0)
    assert np.array_equal(plain.range_m[untouched], carved.range_m[untouched])
    assert np.array_equal(plain.reflectivity[untouched], carved.reflectivity[untouched])


@pytest.mark.parametrize("footprint", [False, True], ids=["four beams", "footprint rule"])
def test_the_centre_scans_own_surfaces_are_not_carved(footprint):
    cols = slice(W // 2 - 40, W // 2 + 40)
    wall = _beam_points(10.0, slice(20, 45), cols)
    parts = [_disks(wall, 0.2)]
    args = ([*parts, *parts], [np.arange(len(wall))] * 2, [np.eye(4)] * 2, EL, W)
    plain = cast_parts(*args, azimuth_offset_rad=-math.pi)
    free = free_space(wall, HDL64, np.eye(4), parts[0]["normal"] if footprint else None)
    carved = cast_parts(*args, azimuth_offset_rad=-math.pi, free=free)
    for name in ("range_m", "owner", "reflectivity", "cos_incidence"):
        assert np.array_equal(getattr(plain, name), getattr(carved, name))


def test_a_hit_in_front_of_the_surface_in_its_own_beams_footprint_is_carved():
    # The centre scan saw a wall 10 m ahead, and poles 3 m ahead on the columns either side
    # of the test beam: the four beams around the test beam do not all lie behind a disk 5 m
    # ahead, but the centre beam the test beam coincides with saw the wall through that spot.
    cols = slice(W // 2 - 40, W // 2 + 40)
    wall = _beam_points(10.0, slice(20, 45), cols)
    k, j = 30, W // 2
    pole = np.vstack([_beam_points(3.0, slice(k, k + 1), slice(c, c + 1)) for c in (j - 1, j + 1)])
    keep = ~np.any(np.all(np.isclose(wall[:, None] / 10.0, pole[None] / 3.0), axis=2), axis=1)
    centre = np.vstack([wall[keep], pole])
    lent = _beam_points(5.0, slice(k, k + 1), slice(j, j + 1))
    wall_disks, pole_disks = _disks(wall[keep], 0.2), _disks(pole, 0.004)  # a pole is thin
    parts = [{f: np.concatenate([wall_disks[f], pole_disks[f]]) for f in wall_disks}]
    parts.append(_disks(lent, 0.05))
    args = (parts, [np.arange(len(centre)), np.arange(1)], [np.eye(4)] * 2, EL, W)
    facing = parts[0]["normal"]
    four_only = cast_parts(
        *args, azimuth_offset_rad=-math.pi, free=free_space(centre, HDL64, np.eye(4))
    )
    both = cast_parts(
        *args, azimuth_offset_rad=-math.pi, free=free_space(centre, HDL64, np.eye(4), facing)
    )
    assert four_only.range_m[k, j] == pytest.approx(5.0, rel=1e-2)
    assert both.range_m[k, j] == pytest.approx(10.0, rel=1e-2)
    # The poles' own beams keep the poles: their footprints hold the poles themselves.
    assert both.range_m[k, j - 1] == pytest.approx(3.0, rel=1e-2)
    assert both.range_m[k, j + 1] == pytest.approx(3.0, rel=1e-2)


def test_the_bound_per_beam_equals_testing_every_hit_on_its_own():
    rng = np.random.default_rng(3)
    image = rng.uniform(2.0, 60.0, (len(EL), W))
    image[rng.random(image.shape) < 0.1] = np.inf  # beams without a return
    space = FreeSpace(image, EL, np.eye(4), CARVE_NOISE_SIGMAS * HDL64.range_accuracy_m)
    rows, columns = 16, 512
    el = np.sort(rng.uniform(EL[1], EL[-2], rows))
    az = (np.arange(columns) + 0.5) * 2 * math.pi / columns - math.pi
    best = rng.uniform(1.0, 50.0, (rows, columns))
    best[rng.random(best.shape) < 0.1] = np.inf
    floor = carve_floor(space, best, el, az)
    step = 2 * math.pi / W
    checked = 0
    for k in range(rows):
        for j in range(columns):
            t = best[k, j]
            if not np.isfinite(t):
                assert floor[k, j] == 0.0
                continue
            c = (az[j] + math.pi) / step - 0.5
            if abs(c - round(c)) < 1e-3:
                continue  # on a bin's edge the coarse angle may pick the other neighbour
            above = int(np.searchsorted(EL, el[k]))
            j0 = math.floor(c) % W
            seen = image[above - 1 : above + 1][:, [j0, (j0 + 1) % W]]
            for u in (t, 1.5 * t, 3.0 * t):  # its hits: the nearest and others behind
                limit = u * (1 + CARVE_SHARE) + space.margin_m
                brute = bool(np.all(np.isfinite(seen)) and np.all(seen > limit))
                assert brute == (u < floor[k, j]) or abs(u - floor[k, j]) < 1e-9
                checked += 1
    assert checked > 20000


def test_nearest_hits_without_a_floor_is_the_cast_pass_rule():
    rng = np.random.default_rng(1)
    pix = rng.integers(0, 8 * 16, 500)
    t = rng.uniform(1.0, 30.0, 500)
    cos = rng.uniform(0.1, 1.0, 500)
    best, best_cos = nearest_hits(pix, t, cos, np.zeros((8, 16)))
    for p in range(8 * 16):
        mine = np.flatnonzero(pix == p)
        if not mine.size:
            assert best.flat[p] == np.inf and best_cos.flat[p] == 1.0
            continue
        first = mine[np.argmin(t[mine])]
        assert best.flat[p] == t[first] and best_cos.flat[p] == cos[first]
    floor = np.full((8, 16), 15.0)
    best2, _ = nearest_hits(pix, t, cos, floor)
    assert np.all((best2 >= 15.0) | np.isinf(best2))
