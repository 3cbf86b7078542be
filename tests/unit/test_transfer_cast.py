"""The cast's pass 1 tests only the beams a surfel's angular bounds keep: it must find exactly
the hits that testing every beam of the grid finds."""

from __future__ import annotations

import math

import numpy as np

from lads.transfer.cast import _HitBuffers, _record_hits

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
