"""The procedural street: a seeded, endless straight street along +x, built in 100 m blocks.

World frame: x along the street, y to the left, z up, z = 0 on the road surface. Cross
section (|y|, m): two 3.5 m driving lanes (|y| < 3.5) with a dashed centre line and solid
edge lines, parking strips to 5.6, a 13 cm curb, sidewalk to 9.0, then front yards (grass,
soil or paving) and buildings set back 11-17 m, with a second row 30-45 m out.

Each block's content depends only on (seed, block index), so a sequence of 5 frames sees the
same street as the first 5 frames of a sequence of 20. The ego vehicle drives in the right
lane (y = -1.75 m) at 10 m/s with a slight lane-keeping sway; two cars travel in its lane
(one ahead pulling away, one behind falling back) and oncoming cars use the left lane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from lads.synth.geometry import BOX, CYLINDER, ELLIPSOID, Primitives
from lads.synth.parts import BUILDING_PARTS, Part

SENSOR_HEIGHT_M = 1.73  # KITTI's HDL-64E mount
EGO_SPEED_M_S = 10.0
FRAME_PERIOD_S = 0.1
LANE_CENTRE_M = 1.75
EDGE_LINE_M = 3.5
ROAD_HALF_WIDTH_M = 5.6
CURB_HEIGHT_M = 0.13
CURB_TOP_WIDTH_M = 0.25
SIDEWALK_OUTER_M = 9.0
BLOCK_M = 100.0
_LINE_HALF_WIDTH_M = 0.075
_MAX_ONCOMING_M_S = 14.0
_VIEW_MARGIN_M = 220.0  # > every shipped profile's max range (200 m)


@dataclass
class _Builder:
    """Accumulates primitives (world coordinates) for one scene."""

    rows: list[tuple[int, tuple[float, ...], tuple[float, ...], int, int, float, float]] = field(
        default_factory=list
    )

    def box(
        self,
        lo: tuple[float, float, float],
        hi: tuple[float, float, float],
        part: int,
        inst: int = 0,
        rho: float = 1.0,
        speed: float = 0.0,
    ) -> None:
        params = (lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])
        self.rows.append((BOX, params, params, part, inst, rho, speed))

    def cylinder(
        self,
        x: float,
        y: float,
        radius: float,
        z0: float,
        z1: float,
        part: int,
        inst: int = 0,
        rho: float = 1.0,
        speed: float = 0.0,
    ) -> None:
        bbox = (x - radius, x + radius, y - radius, y + radius, z0, z1)
        self.rows.append((CYLINDER, (x, y, radius, z0, z1, 0.0), bbox, part, inst, rho, speed))

    def ellipsoid(
        self,
        centre: tuple[float, float, float],
        radii: tuple[float, float, float],
        part: int,
        inst: int = 0,
        rho: float = 1.0,
        speed: float = 0.0,
    ) -> None:
        bbox = tuple(c + s * r for c, r in zip(centre, radii, strict=True) for s in (-1, 1))
        self.rows.append((ELLIPSOID, (*centre, *radii), bbox, part, inst, rho, speed))

    def build(self) -> Primitives:
        kind, params, bbox, part, inst, rho, speed = zip(*self.rows, strict=True)
        return Primitives(
            kind=np.array(kind, dtype=np.int8),
            params=np.array(params, dtype=np.float64),
            bbox=np.array(bbox, dtype=np.float64),
            part=np.array(part, dtype=np.uint8),
            instance=np.array(inst, dtype=np.uint16),
            rho_scale=np.array(rho, dtype=np.float32),
            speed_x=np.array(speed, dtype=np.float64),
        )


@dataclass(frozen=True, slots=True)
class Scene:
    """Primitives plus the ground layout of the blocks a sequence can see.

    Attributes:
        prims: every object.
        yards: per side (left y > 0, right y < 0), x breakpoints (K,) and the ground part
            (K,) from each breakpoint on, for |y| >= SIDEWALK_OUTER_M.
        crosswalks: (M, 2) x intervals of zebra crossings.
    """

    prims: Primitives
    yards: tuple[tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]], ...]
    crosswalks: npt.NDArray[np.float64]

    def ground_part(
        self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64], raised: npt.NDArray[np.bool_]
    ) -> npt.NDArray[np.uint8]:
        """Ground part at world (x, y); `raised` marks hits on the raised (curb-level) plane."""
        ay = np.abs(y)
        part = np.full(x.shape, Part.ROAD, dtype=np.uint8)
        dash = (ay < _LINE_HALF_WIDTH_M) & (np.mod(x, 9.0) < 3.0)
        part[dash | (np.abs(ay - EDGE_LINE_M) < _LINE_HALF_WIDTH_M)] = Part.LANE_MARKING
        lo, hi = self.crosswalks[:, 0], self.crosswalks[:, 1]
        k = np.clip(np.searchsorted(lo, x, side="right") - 1, 0, max(len(lo) - 1, 0))
        on_zebra = (x >= lo[k]) & (x <= hi[k]) if len(lo) else np.zeros(x.shape, dtype=bool)
        stripe = np.mod(y + 0.25, 1.0) < 0.5
        part[on_zebra & stripe & (ay < ROAD_HALF_WIDTH_M - 0.4)] = Part.CROSSWALK
        part[raised] = Part.SIDEWALK
        part[raised & (ay < ROAD_HALF_WIDTH_M + CURB_TOP_WIDTH_M)] = Part.CURB
        for side, (breaks, parts) in zip((1.0, -1.0), self.yards, strict=True):
            yard = raised & (ay >= SIDEWALK_OUTER_M) & (np.sign(y) == side)
            idx = np.clip(np.searchsorted(breaks, x[yard], side="right") - 1, 0, len(breaks) - 1)
            part[yard] = parts[idx]
        return part


def ego_pose(seed: int, time_s: float) -> npt.NDArray[np.float64]:
    """(4, 4) float64 sensor -> world pose at `time_s`: right lane, slight sway in y."""
    phase = float(np.random.default_rng([seed, 7]).uniform(0, 2 * math.pi))
    omega, amp = 2 * math.pi / 7.0, 0.12
    y = -LANE_CENTRE_M + amp * math.sin(omega * time_s + phase)
    yaw = math.atan2(amp * omega * math.cos(omega * time_s + phase), EGO_SPEED_M_S)
    pose = np.eye(4)
    pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    pose[:3, 3] = [EGO_SPEED_M_S * time_s, y, SENSOR_HEIGHT_M]
    return pose


def build_scene(seed: int, duration_s: float) -> Scene:
    """The street a sequence of `duration_s` seconds can see (blocks around the ego path)."""
    x_lo = -_VIEW_MARGIN_M
    x_hi = (EGO_SPEED_M_S + _MAX_ONCOMING_M_S) * duration_s + _VIEW_MARGIN_M
    builder = _Builder()
    _traffic(builder, np.random.default_rng([seed, 3]))
    yards: tuple[list[npt.NDArray[np.float64]], ...] = ([], [])
    yard_parts: tuple[list[npt.NDArray[np.uint8]], ...] = ([], [])
    crosswalks = []
    for b in range(math.floor(x_lo / BLOCK_M), math.floor(x_hi / BLOCK_M) + 1):
        rng = np.random.default_rng([seed, 11, b + 2**20])
        x0, ids = b * BLOCK_M, _InstanceIds(b)
        for i, side in enumerate((1.0, -1.0)):
            breaks, parts = _yards(rng, x0)
            yards[i].append(breaks)
            yard_parts[i].append(parts)
            _buildings(builder, rng, x0, side)
            _parked_cars(builder, rng, x0, side, ids)
            _trees_and_bushes(builder, rng, x0, side)
            _poles_and_signs(builder, rng, x0, side)
            _fences(builder, rng, x0, side)
            _people(builder, rng, x0, side, ids)
        _oncoming(builder, rng, x0, ids)
        if rng.random() < 0.5:
            xc = x0 + rng.uniform(10, 90)
            crosswalks.append((xc, xc + 4.0))
    return Scene(
        prims=builder.build(),
        yards=tuple((np.concatenate(yards[i]), np.concatenate(yard_parts[i])) for i in range(2)),
        crosswalks=np.array(crosswalks, dtype=np.float64).reshape(-1, 2),
    )


class _InstanceIds:
    """Instance ids unique over 255 consecutive blocks, the same whatever the sequence length.

    Ids 1-255 are the ego-lane traffic; block b uses 256 * (1 + b mod 255) + 0..255.
    """

    def __init__(self, block: int) -> None:
        self.base, self.count = 256 * (1 + block % 255), 0

    def next(self) -> int:
        self.count += 1
        return self.base + self.count - 1


def _car(
    b: _Builder,
    x_rear: float,
    y_centre: float,
    heading: float,
    rng: np.random.Generator,
    part: int,
    inst: int,
    speed: float = 0.0,
) -> float:
    """Body and cabin boxes of one car (or van); returns its length, m."""
    van = rng.random() < 0.12
    length = rng.uniform(4.6, 5.3) if van else rng.uniform(3.9, 4.9)
    width = rng.uniform(1.75, 2.0) if van else rng.uniform(1.7, 1.9)
    height = rng.uniform(1.9, 2.2) if van else rng.uniform(1.4, 1.6)
    rho = float(np.clip(rng.lognormal(np.log(0.8), 0.6), 0.1, 1.8))  # paint colour
    y0, y1, body_top = y_centre - width / 2, y_centre + width / 2, rng.uniform(0.8, 0.95)
    b.box((x_rear, y0, 0.2), (x_rear + length, y1, body_top), part, inst, rho, speed)
    a, c = (0.22, 0.95) if van else (0.3, 0.82)  # cabin span behind the front, / length
    start, end = (a, c) if heading < 0 else (1.0 - c, 1.0 - a)  # from x_rear, / length
    lo = (x_rear + start * length, y0 + 0.08, body_top)
    b.box(lo, (x_rear + end * length, y1 - 0.08, height), part, inst, rho, speed)
    return float(length)


def _traffic(b: _Builder, rng: np.random.Generator) -> None:
    """One car ahead of the ego pulling away and one behind falling back, in the ego lane."""
    y = -LANE_CENTRE_M
    ahead = EGO_SPEED_M_S + rng.uniform(0.8, 2.5)
    _car(b, rng.uniform(14, 26), y, 1.0, rng, Part.MOVING_CAR, 1, ahead)
    behind = EGO_SPEED_M_S - rng.uniform(0.8, 2.5)
    _car(b, -rng.uniform(17, 27), y, 1.0, rng, Part.MOVING_CAR, 2, behind)


def _oncoming(b: _Builder, rng: np.random.Generator, x0: float, ids: _InstanceIds) -> None:
    x = x0 + rng.uniform(0, 40)
    while x < x0 + BLOCK_M - 6:
        speed = -rng.uniform(8.0, _MAX_ONCOMING_M_S)
        y = LANE_CENTRE_M + rng.uniform(-0.2, 0.2)
        x += _car(b, x, y, -1.0, rng, Part.MOVING_CAR, ids.next(), speed) + rng.uniform(25, 80)


def _parked_cars(
    b: _Builder, rng: np.random.Generator, x0: float, side: float, ids: _InstanceIds
) -> None:
    x = x0 + rng.uniform(0, 5)
    while x < x0 + BLOCK_M - 6:
        if rng.random() < 0.7:
            y = side * (ROAD_HALF_WIDTH_M - 1.15 - rng.uniform(0, 0.25))
            x += _car(b, x, y, side * -1.0, rng, Part.PARKED_CAR, ids.next())
            x += rng.uniform(0.8, 3.0)
        else:
            x += rng.uniform(4, 12)


def _buildings(b: _Builder, rng: np.random.Generator, x0: float, side: float) -> None:
    x = x0 + rng.uniform(0, 6)
    while True:
        width = rng.uniform(8, 28)
        if x + width > x0 + BLOCK_M - 1:
            break
        front, depth = rng.uniform(11, 17), rng.uniform(8, 18)
        height = rng.uniform(15, 22) if rng.random() < 0.2 else rng.uniform(5, 13)
        ys = sorted((side * front, side * (front + depth)))
        part = BUILDING_PARTS[int(rng.integers(len(BUILDING_PARTS)))]
        rho = float(rng.lognormal(0.0, 0.25))
        b.box((x, ys[0], CURB_HEIGHT_M), (x + width, ys[1], height), part, rho=rho)
        x += width + (rng.uniform(10, 25) if rng.random() < 0.15 else rng.uniform(1.5, 10))
    x = x0 + rng.uniform(0, 30)
    while x < x0 + BLOCK_M - 20:
        width = min(rng.uniform(20, 45), x0 + BLOCK_M - 1 - x)
        front = rng.uniform(30, 45)
        ys = sorted((side * front, side * (front + rng.uniform(15, 25))))
        part = BUILDING_PARTS[int(rng.integers(len(BUILDING_PARTS)))]
        b.box(
            (x, ys[0], CURB_HEIGHT_M),
            (x + width, ys[1], rng.uniform(12, 28)),
            part,
            rho=float(rng.lognormal(0.0, 0.25)),
        )
        x += width + rng.uniform(5, 30)


def _trees_and_bushes(b: _Builder, rng: np.random.Generator, x0: float, side: float) -> None:
    x = x0 + rng.uniform(2, 12)
    while x < x0 + BLOCK_M - 2:
        y = side * (SIDEWALK_OUTER_M - 0.7 if rng.random() < 0.7 else rng.uniform(9.8, 10.6))
        radius, top = rng.uniform(0.12, 0.25), rng.uniform(1.8, 3.2)
        rxy, rz = rng.uniform(1.3, 2.8), rng.uniform(1.2, 2.5)
        b.cylinder(x, y, radius, CURB_HEIGHT_M, top + 0.5 * rz, Part.TRUNK)
        b.ellipsoid((x, y, top + 0.8 * rz), (rxy, rxy * rng.uniform(0.85, 1.15), rz), Part.CROWN)
        x += rng.uniform(7, 20)
    for _ in range(int(rng.integers(1, 5))):
        r = rng.uniform(0.5, 1.2)
        centre = (x0 + rng.uniform(2, 98), side * rng.uniform(9.6, 10.8), CURB_HEIGHT_M + 0.5 * r)
        b.ellipsoid(centre, (r, r * rng.uniform(0.8, 1.2), 0.8 * r), Part.BUSH)


def _poles_and_signs(b: _Builder, rng: np.random.Generator, x0: float, side: float) -> None:
    y = side * (ROAD_HALF_WIDTH_M + 0.5)
    x = x0 + rng.uniform(3, 20)
    while x < x0 + BLOCK_M - 1:
        top = rng.uniform(6.5, 8.5)
        b.cylinder(x, y, rng.uniform(0.09, 0.12), CURB_HEIGHT_M, top, Part.LIGHT_POLE)
        arm_end = y - side * rng.uniform(1.2, 2.0)
        ys = sorted((y, arm_end))
        b.box((x - 0.06, ys[0], top - 0.12), (x + 0.06, ys[1], top), Part.LIGHT_POLE)
        x += rng.uniform(25, 35)
    for _ in range(int(rng.integers(1, 3))):
        x, y_post = x0 + rng.uniform(2, 98), side * (ROAD_HALF_WIDTH_M + 0.35)
        top, size = rng.uniform(2.4, 2.9), rng.uniform(0.5, 0.75)
        b.cylinder(x, y_post, 0.035, CURB_HEIGHT_M, top, Part.SIGN_POST)
        face = x - 0.06 if side < 0 else x + 0.03  # faces the traffic of its side
        lo = (face, y_post - size / 2, top - size + 0.1)
        b.box(lo, (face + 0.03, y_post + size / 2, top + 0.1), Part.TRAFFIC_SIGN)


def _fences(b: _Builder, rng: np.random.Generator, x0: float, side: float) -> None:
    if rng.random() < 0.6:
        x, length = x0 + rng.uniform(0, 80), rng.uniform(6, 20)
        ys = sorted((side * (SIDEWALK_OUTER_M + 0.15), side * (SIDEWALK_OUTER_M + 0.2)))
        height = CURB_HEIGHT_M + rng.uniform(0.9, 1.6)
        b.box((x, ys[0], CURB_HEIGHT_M), (x + length, ys[1], height), Part.FENCE)


def _people(
    b: _Builder, rng: np.random.Generator, x0: float, side: float, ids: _InstanceIds
) -> None:
    for _ in range(int(rng.poisson(3.5))):
        kid, walking = rng.random() < 0.2, rng.random() < 0.5
        height = rng.uniform(1.0, 1.35) if kid else rng.uniform(1.55, 1.9)
        part = (
            (Part.WALKING_KID if walking else Part.KID)
            if kid
            else (Part.WALKING_ADULT if walking else Part.ADULT)
        )
        speed = rng.choice([-1.0, 1.0]) * rng.uniform(0.9, 1.6) if walking else 0.0
        x, y = x0 + rng.uniform(1, 99), side * rng.uniform(ROAD_HALF_WIDTH_M + 1.0, 7.8)
        inst, rho = ids.next(), float(rng.lognormal(0.0, 0.3))
        head = 0.065 * height
        b.cylinder(
            x,
            y,
            0.125 * height,
            CURB_HEIGHT_M,
            CURB_HEIGHT_M + height - 2 * head,
            part,
            inst,
            rho,
            speed,
        )
        centre = (x, y, CURB_HEIGHT_M + height - head)
        b.ellipsoid(centre, (head, head, 1.1 * head), part, inst, rho, speed)


def _yards(
    rng: np.random.Generator, x0: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]:
    breaks, parts, x = [], [], x0
    while x < x0 + BLOCK_M:
        breaks.append(x)
        parts.append(rng.choice([Part.GRASS, Part.SOIL, Part.SIDEWALK], p=[0.55, 0.15, 0.3]))
        x += rng.uniform(5, 25)
    return np.array(breaks), np.array(parts, dtype=np.uint8)
