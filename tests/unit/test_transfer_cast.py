"""The cast's parts: pass 1 tests only the beams a surfel's angular bounds keep and must find
exactly the hits that testing every beam finds; silhouettes; what lies beyond the source's
view."""

from __future__ import annotations

import math

import numpy as np

from lads.transfer.bounds import (
    ATAN2_ERROR_RAD,
    angular_radius,
    azimuth_radius,
    coarse_atan2,
)
from lads.transfer.cast import _HitBuffers, _record_hits
from lads.transfer.fov import hidden_beyond_view
from lads.transfer.surfels import silhouette_sides

ROWS, COLUMNS = 32, 1024


def _surfels(rng: np.random.Generator, m: int) -> dict[str, np.ndarray]:
    """Random ellipses facing the sensor: half with their axes in the plane, half with the
    axes of a grazing surfel whose stretching stopped short of the plane (as surfels.py
    makes them below min_cos)."""
    direction = rng.normal(size=(m, 3))
    direction[:, 2] *= 0.3
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    centre = direction * rng.uniform(2.0, 40.0, (m, 1))
    normal = rng.normal(size=(m, 3))
    normal -= direction * (np.einsum("ij,ij->i", normal, direction)[:, None] + 0.5)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    axes = []
    for _ in range(2):
        v = rng.normal(size=(m, 3))
        v -= normal * np.einsum("ij,ij->i", v, normal)[:, None]
        v *= rng.uniform(0.02, 0.6, (m, 1)) / np.linalg.norm(v, axis=1, keepdims=True)
        off_plane = np.arange(m) % 2 == 1
        v[off_plane] += direction[off_plane] * rng.uniform(-0.3, 0.3, (off_plane.sum(), 1))
        axes.append(v)
    radius = np.linalg.norm(axes[0], axis=1) + np.linalg.norm(axes[1], axis=1)
    return {"centre": centre, "normal": normal, "a": axes[0], "b": axes[1], "radius": radius}


def _every_beam(s: dict[str, np.ndarray], el: np.ndarray) -> tuple[set, set]:
    """(beam, surfel) pairs that testing every beam finds well inside / not outside the
    ellipse (|alpha^2 + beta^2 - 1| > 1e-9 decides; rounding may go either way at the rim)."""
    az = (np.arange(COLUMNS) + 0.5) * 2.0 * math.pi / COLUMNS
    d = np.stack(
        np.broadcast_arrays(
            np.cos(el)[:, None] * np.cos(az), np.cos(el)[:, None] * np.sin(az), np.sin(el)[:, None]
        ),
        axis=-1,
    ).reshape(-1, 3)
    inside, near = set(), set()
    for i in range(len(s["centre"])):
        c, n, a, b = s["centre"][i], s["normal"][i], s["a"][i], s["b"][i]
        if np.linalg.norm(c) <= s["radius"][i]:
            continue
        denom = d @ n
        t = (c @ n) / np.where(np.abs(denom) < 1e-9, np.nan, denom)
        e = t[:, None] * d - c
        g = np.array([[a @ a, a @ b], [a @ b, b @ b]])
        ab = np.linalg.solve(g, np.stack([e @ a, e @ b]))
        d2 = (ab**2).sum(axis=0)
        ok = t > 0
        inside |= {(int(p), i) for p in np.flatnonzero(ok & (d2 < 1.0 - 1e-9))}
        near |= {(int(p), i) for p in np.flatnonzero(ok & (d2 <= 1.0 + 1e-9))}
    return inside, near


def test_pass_one_finds_the_hits_that_testing_every_beam_finds() -> None:
    rng = np.random.default_rng(7)
    s = _surfels(rng, 240)
    el = np.radians(np.linspace(-30.0, 10.0, ROWS))
    buffers = _HitBuffers.empty(1024)
    out = _HitBuffers(
        *_record_hits(
            s["centre"],
            s["normal"],
            s["a"],
            s["b"],
            s["radius"],
            np.ones(len(s["centre"])),
            np.ones(len(s["centre"])),
            np.zeros(len(s["centre"]), bool),
            np.arange(len(s["centre"]), dtype=np.int64),
            np.eye(3),
            np.zeros(3),
            0,
            el,
            0.0,
            COLUMNS,
            1e3,
            0.0,
            np.full((ROWS, COLUMNS), np.inf),
            np.ones((ROWS, COLUMNS)),
            *buffers.arrays(),
            0,
        )
    )
    found = set(zip(out.pix[: out.n].tolist(), out.i[: out.n].tolist(), strict=True))
    inside, near = _every_beam(s, el)
    assert len(inside) > 200  # the surfels meet beams: the comparison is not empty
    assert inside <= found <= near


def test_the_angular_bounds_hold_every_point_of_the_ellipse_and_are_tight() -> None:
    rng = np.random.default_rng(3)
    s = _surfels(rng, 400)
    phase = np.linspace(0.0, 2.0 * math.pi, 721)
    slack = []
    for c, a, b in zip(s["centre"], s["a"], s["b"], strict=True):
        rim = c + np.cos(phase)[:, None] * a + np.sin(phase)[:, None] * b
        r = float(np.linalg.norm(c))
        u = c / r
        half = angular_radius(*a, *b, *u, r)
        if half < 0.0:
            continue
        angle = np.arccos(np.clip(rim @ u / np.linalg.norm(rim, axis=1), -1.0, 1.0))
        width = azimuth_radius(a[0], a[1], b[0], b[1], c[0], c[1])
        turn = np.angle(np.exp(1j * (np.arctan2(rim[:, 1], rim[:, 0]) - math.atan2(c[1], c[0]))))
        assert angle.max() <= half
        assert np.abs(turn).max() <= width
        slack.append(half / max(angle.max(), 1e-12))
    # Bounds, yet close: most ellipses span at least half of what their bound allows.
    assert len(slack) > 300 and np.median(slack) < 2.0


def test_the_coarse_angle_is_within_its_error_bound_all_round_the_circle() -> None:
    # Every octant's edges (the axes and the diagonals, both zeros), the two sides of -pi /
    # pi, and lengths from tiny to large.
    edges = np.arange(8) * math.pi / 4
    angles = np.concatenate([np.linspace(-math.pi, math.pi, 200_001), edges, edges + 1e-12])
    worst = 0.0
    for length in (1e-9, 1.0, 3e4):
        for a in angles:
            y, x = length * math.sin(a), length * math.cos(a)
            for yy in (y, -0.0) if y == 0.0 else (y,):
                off = abs(coarse_atan2(yy, x) - math.atan2(yy, x))
                worst = max(worst, min(off, 2.0 * math.pi - off))  # -pi and pi are one angle
    assert 1e-7 < worst <= ATAN2_ERROR_RAD  # coarse indeed, yet within its bound
    assert coarse_atan2(0.0, 0.0) == 0.0


def test_beyond_the_source_view_a_lent_surface_behind_a_moving_thing_is_hidden() -> None:
    # Rings 0-1 lie below the source's view; the edge ring 2 shows a moving car at 3 m in
    # columns 4-6; below it neighbours lend road at 3.5 m (behind the car) and at 2 m (in
    # front of it), and one beam hits the scan's own surfel.
    rows, cols = 5, 12
    covered = np.array([False, False, True, True, True])
    range_m = np.full((rows, cols), 8.0)
    moving_here = np.zeros((rows, cols), bool)
    lent = np.zeros((rows, cols), bool)
    moving_here[2, 4:7] = True
    range_m[2, 4:7] = 3.0
    lent[:2, :] = True
    range_m[:2, :] = 3.5
    range_m[0, 5] = 2.0
    lent[1, 8] = False
    hidden = hidden_beyond_view(range_m, moving_here, lent, covered)
    expected = np.zeros((rows, cols), bool)
    expected[:2, 3:8] = True  # the car's columns and one on either side
    expected[0, 5] = False  # road in front of the car
    assert np.array_equal(hidden, expected)
    # Nothing moving at the edge, or every ring covered: nothing is hidden.
    assert not hidden_beyond_view(range_m, np.zeros_like(moving_here), lent, covered).any()
    assert not hidden_beyond_view(range_m, moving_here, lent, np.ones(rows, bool)).any()


def test_far_ground_whose_next_ring_lies_far_behind_on_its_plane_is_no_silhouette() -> None:
    # One column of flat ground 1.8 m below the sensor, rings 1.33 deg apart: each next ring
    # lies 30-50 % farther, yet on the same plane, so no side is a silhouette; a post standing
    # in front of the third ring makes the ring below it one (its neighbour is off its plane).
    el = np.radians(np.array([-8.0, -6.67, -5.34, -4.01]))[::-1]  # row 0 is the highest
    rng = 1.8 / -np.sin(el)
    view = np.stack([np.cos(el), np.zeros(4), np.sin(el)], axis=1)
    pts = view * rng[:, None]
    normal = np.tile([0.0, 0.0, 1.0], (4, 1))
    index = np.arange(4, dtype=np.int64).reshape(4, 1)
    row, col = np.arange(4, dtype=np.int64), np.zeros(4, np.int64)
    args = (0.1, 1, pts, normal)
    _, edge_b = silhouette_sides(rng.reshape(4, 1), index, row, col, rng, *args)
    assert not edge_b.any()
    pts[1] = view[1] * (0.6 * rng[1])  # a post in front of ring 1 faces the sensor
    normal[1] = -view[1]
    rng[1] *= 0.6
    _, edge_b = silhouette_sides(rng.reshape(4, 1), index, row, col, rng, *args)
    assert edge_b.tolist() == [False, True, False, False]


def test_silhouette_sides_mark_returns_whose_next_return_is_missing_or_behind() -> None:
    # A 4 x 6 image: a wall at 10 m over columns 1-4 of rows 1-2, background at 30 m
    # elsewhere; row 3 is empty (sky) and so is pixel (1, 0) (a lost return).
    rng_img = np.full((4, 6), 30.0)
    rng_img[1:3, 1:5] = 10.0
    occupied = np.ones((4, 6), bool)
    occupied[3, :] = False
    occupied[1, 0] = False
    row, col = np.nonzero(occupied)
    index = np.full((4, 6), -1, np.int64)
    index[row, col] = np.arange(len(row))
    # Rows 2 deg apart in elevation (row 0 highest), columns 2 deg in azimuth; every return
    # faces the sensor, as a wall and a background square to it do.
    el, az = np.radians(3.0 - 2.0 * row), np.radians(2.0 * col)
    view = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    pts = view * rng_img[row, col][:, None]
    edge_a, edge_b = silhouette_sides(
        rng_img,
        index,
        row.astype(np.int64),
        col.astype(np.int64),
        rng_img[row, col],
        0.1,
        1,
        pts,
        -view,
    )
    a = {(int(r), int(c)) for r, c in zip(row[edge_a], col[edge_a], strict=True)}
    b = {(int(r), int(c)) for r, c in zip(row[edge_b], col[edge_b], strict=True)}
    # Along azimuth: the wall's ends where the background lies beside them; not where the
    # lost return does (a dropout is no silhouette), and not the background beside the
    # nearer wall (its neighbour lies in front).
    assert a == {(1, 4), (2, 1), (2, 4)}
    # Along elevation: the wall's lower row, with background behind it below; not the upper
    # row under the empty one (sky and dropouts look the same), nor the first row.
    assert b == {(1, 1), (1, 2), (1, 3), (1, 4)}
