"""Vectorised analytic ray casting of boxes, vertical cylinders and ellipsoids.

All geometry is expressed in a world-aligned frame centred on the sensor (world axes, origin
at the sensor), so every ray starts at the origin. Each primitive is culled to the block of
beams (a range of channels x a range of azimuth columns) that can reach its bounding box,
and intersected only there, as numpy views; the only Python loop runs over primitives.
Normals are recomputed afterwards, once per point, from the hit position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

BOX, CYLINDER, ELLIPSOID = 0, 1, 2
GROUND_PLANE, CURB_FACE = -1, -2  # primitive index of ground hits
_ANGLE_MARGIN_RAD = 1e-6

F64 = npt.NDArray[np.float64]

# Which of the 6 parameters of a primitive are x, y or z coordinates (per primitive kind):
# box (x0, x1, y0, y1, z0, z1); cylinder (cx, cy, radius, z0, z1, -); ellipsoid (cx, cy, cz,
# rx, ry, rz).
_COORD_MASKS = np.zeros((3, 3, 6))
_COORD_MASKS[BOX] = [[1, 1, 0, 0, 0, 0], [0, 0, 1, 1, 0, 0], [0, 0, 0, 0, 1, 1]]
_COORD_MASKS[CYLINDER] = [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 0, 1, 1, 0]]
_COORD_MASKS[ELLIPSOID] = [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0]]


@dataclass(frozen=True, slots=True)
class Primitives:
    """Scene primitives in world coordinates (m), one row each.

    Attributes:
        kind: (P,) int8, BOX, CYLINDER or ELLIPSOID.
        params: (P, 6) float64, see _COORD_MASKS for the meaning per kind.
        bbox: (P, 6) float64 axis-aligned bounds (x0, x1, y0, y1, z0, z1).
        part: (P,) uint8 generator part code (lads.synth.scene.Part).
        instance: (P,) uint16 instance id, 0 for stuff.
        rho_scale: (P,) float32 per-object reflectance factor (paint colour, facade).
        speed_x: (P,) float64 velocity along +x, m/s (0 for static objects).
    """

    kind: npt.NDArray[np.int8]
    params: F64
    bbox: F64
    part: npt.NDArray[np.uint8]
    instance: npt.NDArray[np.uint16]
    rho_scale: npt.NDArray[np.float32]
    speed_x: F64

    def at(self, time_s: float, origin: F64) -> tuple[F64, F64]:
        """Params and bboxes at `time_s`, relative to the world point `origin` (3,)."""
        shift = np.zeros((len(self.kind), 3))
        shift[:, 0] = self.speed_x * time_s
        shift -= origin
        params = self.params + np.einsum("pk,pkj->pj", shift, _COORD_MASKS[self.kind])
        bbox = self.bbox + np.repeat(shift, 2, axis=1)
        return params, bbox


@dataclass(frozen=True, slots=True)
class Beams:
    """Unit beam directions of one sweep, world-aligned, (channels, columns) each.

    Column j points at world azimuth az0 + (j + 0.5) * step; rows follow `elevation` (rad,
    ascending, channel 0 lowest).
    """

    elevation: F64
    az0: float
    step: float
    dx: F64
    dy: F64
    dz: F64
    inv: tuple[F64, F64, F64]

    @classmethod
    def make(cls, elevation_rad: F64, columns: int, az0: float) -> Beams:
        step = 2.0 * math.pi / columns
        az = az0 + (np.arange(columns) + 0.5) * step
        ce, se = np.cos(elevation_rad)[:, None], np.sin(elevation_rad)[:, None]
        dx, dy = ce * np.cos(az), ce * np.sin(az)
        dz = np.repeat(se, columns, axis=1)
        # Exact zeros would give 0 * inf = NaN on a slab through the origin.
        inv = tuple(1.0 / np.where(d == 0.0, 1e-300, d) for d in (dx, dy, dz))
        return cls(elevation_rad, az0, step, dx, dy, dz, inv)  # type: ignore[arg-type]

    @property
    def shape(self) -> tuple[int, int]:
        return self.dx.shape  # type: ignore[return-value]


def _blocks(beams: Beams, bbox: F64, max_range_m: float) -> list[tuple[int, slice, slice]]:
    """(primitive index, row slice, column slice) of every beam block worth casting."""
    x0, x1, y0, y1, z0, z1 = bbox.T
    near_x = np.maximum(np.maximum(x0, -x1), 0.0)
    near_y = np.maximum(np.maximum(y0, -y1), 0.0)
    d_min = np.hypot(near_x, near_y)
    d_max = np.hypot(np.maximum(np.abs(x0), np.abs(x1)), np.maximum(np.abs(y0), np.abs(y1)))
    el_lo = np.arctan2(z0, np.where(z0 < 0, d_min, d_max)) - _ANGLE_MARGIN_RAD
    el_hi = np.arctan2(z1, np.where(z1 > 0, d_min, d_max)) + _ANGLE_MARGIN_RAD
    rows0 = np.searchsorted(beams.elevation, el_lo, side="left")
    rows1 = np.searchsorted(beams.elevation, el_hi, side="right")
    centre = np.arctan2(0.5 * (y0 + y1), 0.5 * (x0 + x1))
    corners = np.arctan2(np.stack([y0, y0, y1, y1]), np.stack([x0, x1, x0, x1]))
    offsets = np.angle(np.exp(1j * (corners - centre)))
    a_lo = centre + offsets.min(axis=0) - _ANGLE_MARGIN_RAD
    a_hi = centre + offsets.max(axis=0) + _ANGLE_MARGIN_RAD
    cols0 = np.ceil((a_lo - beams.az0) / beams.step - 0.5).astype(np.int64)
    cols1 = np.floor((a_hi - beams.az0) / beams.step - 0.5).astype(np.int64) + 1
    inside = d_min == 0.0
    keep = (d_min <= max_range_m) & (rows1 > rows0) & ((cols1 > cols0) | inside)
    columns = beams.shape[1]
    blocks: list[tuple[int, slice, slice]] = []
    for k in np.flatnonzero(keep):
        rows = slice(int(rows0[k]), int(rows1[k]))
        count = columns if inside[k] else int(cols1[k] - cols0[k])
        if count >= columns:
            blocks.append((int(k), rows, slice(0, columns)))
            continue
        start = int(cols0[k]) % columns
        blocks.append((int(k), rows, slice(start, min(start + count, columns))))
        if start + count > columns:
            blocks.append((int(k), rows, slice(0, start + count - columns)))
    return blocks


def _t_box(b: tuple[F64, F64, F64], p: F64) -> F64:
    t_near = np.full(b[0].shape, -np.inf)
    t_far = np.full(b[0].shape, np.inf)
    for axis in range(3):
        t1, t2 = p[2 * axis] * b[axis], p[2 * axis + 1] * b[axis]
        np.maximum(t_near, np.minimum(t1, t2), out=t_near)
        np.minimum(t_far, np.maximum(t1, t2), out=t_far)
    return np.where((t_near <= t_far) & (t_near > 0.0), t_near, np.inf)


def _t_cylinder(d: tuple[F64, F64, F64], p: F64) -> F64:
    cx, cy, radius, z0, z1 = p[:5]
    a = d[0] * d[0] + d[1] * d[1]
    b = d[0] * cx + d[1] * cy
    disc = b * b - a * (cx * cx + cy * cy - radius * radius)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (b - np.sqrt(disc)) / a
        z = t * d[2]
    return np.where((disc >= 0) & (t > 0) & (z >= z0) & (z <= z1), t, np.inf)


def _t_ellipsoid(d: tuple[F64, F64, F64], p: F64) -> F64:
    c = p[0:3] / p[3:6]
    sx, sy, sz = (d[i] / p[3 + i] for i in range(3))
    a = sx * sx + sy * sy + sz * sz
    b = sx * c[0] + sy * c[1] + sz * c[2]
    disc = b * b - a * (c @ c - 1.0)
    with np.errstate(invalid="ignore"):
        t = (b - np.sqrt(disc)) / a
    return np.where((disc >= 0) & (t > 0), t, np.inf)


def cast_primitives(
    beams: Beams,
    params: F64,
    bbox: F64,
    kind: npt.NDArray[np.int8],
    t_hit: F64,
    prim: npt.NDArray[np.int32],
    max_range_m: float,
) -> None:
    """Intersect every primitive with its beam block; keep the nearest hit per beam.

    Args:
        beams: the sweep's beams.
        params, bbox: (P, 6) primitives relative to the sensor (Primitives.at).
        kind: (P,) primitive kinds.
        t_hit: (channels, columns) nearest hit distance so far, m; updated in place.
        prim: (channels, columns) index of the nearest primitive so far; updated in place.
        max_range_m: primitives entirely beyond this horizontal distance are skipped.
    """
    for k, rows, cols in _blocks(beams, bbox, max_range_m):
        if kind[k] == BOX:
            t = _t_box(tuple(i[rows, cols] for i in beams.inv), params[k])  # type: ignore[arg-type]
        else:
            d = (beams.dx[rows, cols], beams.dy[rows, cols], beams.dz[rows, cols])
            hit = _t_cylinder if kind[k] == CYLINDER else _t_ellipsoid
            t = hit(d, params[k])
        current = t_hit[rows, cols]
        closer = t < current
        np.copyto(current, t, where=closer)
        np.copyto(prim[rows, cols], np.int32(k), where=closer)


def normals(
    point: F64, prim: npt.NDArray[np.int32], params: F64, kind: npt.NDArray[np.int8]
) -> F64:
    """(N, 3) unit surface normal at each hit point (relative coords) of primitive `prim`."""
    n = np.zeros_like(point)
    n[prim == GROUND_PLANE, 2] = 1.0
    curb = np.flatnonzero(prim == CURB_FACE)
    n[curb, 1] = -np.sign(point[curb, 1])
    objects = np.flatnonzero(prim >= 0)
    order = objects[np.argsort(prim[objects], kind="stable")]
    ids, starts = np.unique(prim[order], return_index=True)
    for k, idx in zip(ids, np.split(order, starts[1:]), strict=True):
        p, q = params[k], point[idx]
        if kind[k] == BOX:
            dist = np.abs(q[:, [0, 0, 1, 1, 2, 2]] - p)
            face = dist.argmin(axis=1)
            n[idx, face // 2] = np.where(face % 2 == 0, -1.0, 1.0)
        elif kind[k] == CYLINDER:
            n[idx, 0:2] = (q[:, 0:2] - p[0:2]) / p[2]
        else:
            g = (q - p[0:3]) / (p[3:6] ** 2)
            n[idx] = g / np.linalg.norm(g, axis=1, keepdims=True)
    return n
