"""A synthetic street scan ray-cast for a sensor profile: data lads makes itself.

Tests and `make demo` need a realistic LiDAR frame on a machine without any dataset (and the
real datasets are non-commercial, so none ships with lads). This module ray-casts a fixed
street scene analytically: every beam of the profile (elevation x azimuth) is intersected
with a few dozen primitives (planes, axis-aligned boxes, vertical cylinders, spheres), fully
vectorised over beams; the only Python loop runs over primitives.

The sensor sits at the origin, 1.73 m above the road (KITTI's HDL-64E mount), x along the
street, y to the left, z up. Labels are SemanticKITTI class ids.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.physics.materials import reflectance_for_labels
from lads.sensors.profile import SensorProfile

SENSOR_HEIGHT_M = 1.73
CURB_HEIGHT_M = 0.12
ROAD_HALF_WIDTH_M = 4.0
SIDEWALK_OUTER_M = 6.5  # |y| where the sidewalk ends and terrain patches may start
INTENSITY_NOISE_SIGMA = 0.05  # relative (log-normal) spread of reflectivity per point

CAR, ROAD, SIDEWALK, BUILDING, LANE_MARKING = 10, 40, 48, 50, 60
VEGETATION, TRUNK, TERRAIN, POLE, TRAFFIC_SIGN = 70, 71, 72, 80, 81
SCENE_LABELS = (
    CAR,
    ROAD,
    SIDEWALK,
    BUILDING,
    LANE_MARKING,
    VEGETATION,
    TRUNK,
    TERRAIN,
    POLE,
    TRAFFIC_SIGN,
)

_GROUND_Z = -SENSOR_HEIGHT_M
_RAISED_Z = _GROUND_Z + CURB_HEIGHT_M


@dataclass(frozen=True, slots=True)
class SyntheticScan:
    """One ray-cast frame.

    Attributes:
        xyz: (N, 3) float32 point coordinates, m, sensor frame.
        intensity: (N,) float32 in the profile's intensity encoding (rho * cos(incidence)).
        labels: (N,) uint32 SemanticKITTI class ids (instance bits 0).
        ring: (N,) int64 channel of each point, 0 = lowest beam.
    """

    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    labels: npt.NDArray[np.uint32]
    ring: npt.NDArray[np.int64]

    @property
    def range_m(self) -> npt.NDArray[np.float32]:
        """(N,) float32 range of each point, m."""
        return np.linalg.norm(self.xyz, axis=1)


# Scene, in sensor coordinates (m). A street with a crossing street at x = 8..34 m; facades
# 8.5-14.5 m from the sensor, a second row 60 m out seen through the gaps, open sky beyond
# x = +-100 m (those beams return nothing, as in a real scan).
# Buildings: (x0, x1, front y, depth m, height m); the sign of front y gives the side.
_BUILDINGS = (
    (-100, -62, 9.0, 14, 14), (-56, -28, 10.5, 14, 9), (-22, 8, 8.5, 16, 17),
    (34, 60, 12.0, 14, 11), (66, 100, 9.0, 14, 15),
    (-100, -70, -13.0, 15, 12), (-64, -36, -11.0, 15, 16), (-30, 8, -12.5, 15, 10),
    (80, 100, -12.0, 15, 18),
    (-40, 80, 52.0, 15, 20), (-60, 100, -55.0, 15, 20),
)  # fmt: skip
_CARS_X = {2.1: (-17.0, -9.5, 9.0, 36.0, 44.0), -3.9: (-24.0, -13.0, 5.0, 14.0, 38.0)}
_POLES_XY = ((-20, 5.6), (6.5, 5.6), (36, 5.6), (-12, -5.6), (11.95, -5.6), (40, -5.6))
# Trees: (x, y, crown radius m); bushes: (x, y, radius m).
_TREES = ((-30.0, 7.2, 1.8), (-5.0, 7.2, 1.6), (18.0, 7.2, 2.0), (45.0, 7.4, 1.8),
          (-25.0, -7.3, 1.7), (-2.0, -7.3, 1.9), (28.0, -7.3, 1.6))  # fmt: skip
_BUSHES = ((-8.0, 7.0, 0.9), (-14.0, -7.2, 0.8), (44.0, -7.2, 1.0), (-44.0, 7.2, 0.9))
_HEDGES = (
    (20.0, 28.0, 6.8, 7.6, 1.0), (-44.0, -36.0, -7.6, -6.8, 1.2), (-60.0, -47.0, 6.8, 7.8, 1.4),
    (47.0, 62.0, -7.8, -6.8, 1.1), (-20.0, -16.0, -7.6, -6.8, 0.9),
)  # fmt: skip


def _boxes() -> list[tuple[float, ...]]:
    """Axis-aligned boxes (x0, x1, y0, y1, z0, z1, label)."""
    top = _RAISED_Z
    boxes = []
    for x0, x1, front, depth, height in _BUILDINGS:
        far = front + np.copysign(depth, front)
        boxes.append((x0, x1, min(front, far), max(front, far), top, top + height, BUILDING))
    for y0, xs in _CARS_X.items():
        boxes += [(x, x + 4.3, y0, y0 + 1.8, _GROUND_Z, _GROUND_Z + 1.5, CAR) for x in xs]
    boxes += [(x0, x1, y0, y1, top, top + h, VEGETATION) for x0, x1, y0, y1, h in _HEDGES]
    # A sign plate on the pole at (11.95, -5.6), facing oncoming traffic (and the sensor).
    boxes.append((11.86, 11.9, -6.0, -5.2, top + 1.3, top + 2.0, TRAFFIC_SIGN))
    return boxes


def _cylinders() -> list[tuple[float, ...]]:
    """Vertical cylinders (x, y, radius, z0, z1, label)."""
    z = _RAISED_Z
    poles = [(x, y, 0.1, z, z + 6.0, POLE) for x, y in _POLES_XY]
    return poles + [(x, y, 0.15, z, z + 2.0, TRUNK) for x, y, _ in _TREES]


def _spheres() -> list[tuple[float, ...]]:
    """Spheres (x, y, z, radius, label): tree crowns and bushes."""
    crowns = [(x, y, _RAISED_Z + 2.0 + 0.8 * r, r, VEGETATION) for x, y, r in _TREES]
    return crowns + [(x, y, _RAISED_Z + 0.6 * r, r, VEGETATION) for x, y, r in _BUSHES]


def _ground_label(x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]) -> npt.NDArray[np.uint32]:
    """SemanticKITTI id of the ground at (x, y): road, markings, sidewalk or terrain."""
    ay = np.abs(y)
    label = np.where(ay < ROAD_HALF_WIDTH_M, ROAD, SIDEWALK).astype(np.uint32)
    centre_dash = (ay < 0.075) & (np.mod(x, 9.0) < 3.0)
    edge_line = np.abs(ay - (ROAD_HALF_WIDTH_M - 0.3)) < 0.075
    label[centre_dash | edge_line] = LANE_MARKING
    label[(ay >= SIDEWALK_OUTER_M) & (np.mod(x, 25.0) < 15.0)] = TERRAIN
    return label


class _Hits:
    """Nearest hit so far per beam on the (channels, azimuths) grid."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.t = np.full(shape, np.inf)
        self.normal = np.zeros((*shape, 3))
        self.label = np.zeros(shape, dtype=np.uint32)

    def offer(
        self,
        cols: npt.NDArray[np.intp],
        t: npt.NDArray[np.float64],
        normal: npt.NDArray[np.float64],
        label: int | npt.NDArray[np.uint32],
    ) -> None:
        """Keep the candidate hits (for beams in `cols`) that are nearer than the current."""
        current = self.t[:, cols]
        closer = t < current
        self.t[:, cols] = np.where(closer, t, current)
        self.normal[:, cols] = np.where(closer[..., None], normal, self.normal[:, cols])
        self.label[:, cols] = np.where(closer, label, self.label[:, cols])


def _columns_facing(
    azimuth: npt.NDArray[np.float64], x0: float, x1: float, y0: float, y1: float
) -> npt.NDArray[np.intp]:
    """Azimuth bins whose rays can reach the footprint [x0, x1] x [y0, y1] (origin outside)."""
    centre = np.arctan2(0.5 * (y0 + y1), 0.5 * (x0 + x1))
    corners = np.arctan2([y0, y0, y1, y1], [x0, x1, x0, x1])
    offsets = np.angle(np.exp(1j * (corners - centre)))
    rel = np.angle(np.exp(1j * (azimuth - centre)))
    margin = 1e-3
    return np.flatnonzero((rel >= offsets.min() - margin) & (rel <= offsets.max() + margin))


def _hit_box(d: npt.NDArray[np.float64], box: tuple[float, ...]):  # type: ignore[no-untyped-def]
    lo, hi = np.array(box[0:6:2]), np.array(box[1:6:2])
    # An exactly axis-parallel ray would give 0 * inf = NaN on a face through the origin.
    d = np.where(d == 0.0, 1e-12, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1, t2 = lo * inv, hi * inv
    near, far = np.minimum(t1, t2), np.maximum(t1, t2)
    t_near, t_far = near.max(axis=-1), far.min(axis=-1)
    t = np.where((t_near <= t_far) & (t_near > 0), t_near, np.inf)
    axis = near.argmax(axis=-1)
    normal = np.zeros_like(d)
    sign = -np.sign(np.take_along_axis(d, axis[..., None], axis=-1))
    np.put_along_axis(normal, axis[..., None], sign, axis=-1)
    return t, normal


def _hit_cylinder(d: npt.NDArray[np.float64], cyl: tuple[float, ...]):  # type: ignore[no-untyped-def]
    cx, cy, radius, z0, z1 = cyl[:5]
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = d[..., 0] * cx + d[..., 1] * cy
    disc = b * b - a * (cx * cx + cy * cy - radius * radius)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (b - np.sqrt(disc)) / a
    z = t * d[..., 2]
    t = np.where((disc >= 0) & (t > 0) & (z >= z0) & (z <= z1), t, np.inf)
    t_hit = np.where(np.isfinite(t), t, 0.0)
    normal = np.stack([t_hit * d[..., 0] - cx, t_hit * d[..., 1] - cy, np.zeros_like(t)], axis=-1)
    return t, normal / radius


def _hit_sphere(d: npt.NDArray[np.float64], sph: tuple[float, ...]):  # type: ignore[no-untyped-def]
    centre, radius = np.array(sph[:3]), sph[3]
    b = d @ centre
    disc = b * b - (centre @ centre - radius * radius)
    with np.errstate(invalid="ignore"):
        t = b - np.sqrt(disc)
    t = np.where((disc >= 0) & (t > 0), t, np.inf)
    normal = (np.where(np.isfinite(t), t, 0.0)[..., None] * d - centre) / radius
    return t, normal


def _cast_ground(hits: _Hits, d: npt.NDArray[np.float64]) -> None:
    """Road at -1.73 m, everything beyond the curb raised by 12 cm, plus the curb faces."""
    cols = np.arange(d.shape[1])
    down = d[..., 2] < 0
    up = np.array([0.0, 0.0, 1.0])
    for z, raised in ((_GROUND_Z, False), (_RAISED_Z, True)):
        with np.errstate(divide="ignore"):
            t = np.where(down, z / d[..., 2], np.inf)
        y = np.where(np.isfinite(t), np.where(np.isfinite(t), t, 0.0) * d[..., 1], np.inf)
        t = np.where((np.abs(y) >= ROAD_HALF_WIDTH_M) == raised, t, np.inf)
        hits.offer(cols, t, np.broadcast_to(up, d.shape), 0)
    for side in (1.0, -1.0):
        curb = (
            -200.0,
            200.0,
            side * ROAD_HALF_WIDTH_M,
            side * (ROAD_HALF_WIDTH_M + 0.05),
            _GROUND_Z,
            _RAISED_Z,
        )
        lo, hi = min(curb[2], curb[3]), max(curb[2], curb[3])
        t, normal = _hit_box(d, (curb[0], curb[1], lo, hi, curb[4], curb[5]))
        hits.offer(cols, t, normal, SIDEWALK)


def _cast_scene(d: npt.NDArray[np.float64], azimuth: npt.NDArray[np.float64]) -> _Hits:
    hits = _Hits(d.shape[:2])
    _cast_ground(hits, d)
    pending_ground = hits.label == 0
    prims = [(_hit_box, b, b[:4]) for b in _boxes()]
    prims += [
        (_hit_cylinder, c, (c[0] - c[2], c[0] + c[2], c[1] - c[2], c[1] + c[2]))
        for c in _cylinders()
    ]
    prims += [
        (_hit_sphere, s, (s[0] - s[3], s[0] + s[3], s[1] - s[3], s[1] + s[3])) for s in _spheres()
    ]
    for hit, prim, (x0, x1, y0, y1) in prims:
        cols = _columns_facing(azimuth, x0, x1, y0, y1)
        if cols.size:
            t, normal = hit(d[:, cols], prim)
            hits.offer(cols, t, normal, int(prim[-1]))
    ground = pending_ground & (hits.label == 0) & np.isfinite(hits.t)
    point = d[ground] * hits.t[ground][:, None]
    hits.label[ground] = _ground_label(point[:, 0], point[:, 1])
    return hits


def beam_directions(
    profile: SensorProfile, azimuth_bins: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Unit direction of every beam and the azimuth grid.

    Returns:
        (channels, azimuth_bins, 3) float64 unit vectors, and (azimuth_bins,) float64
        azimuths in rad, bin centres over [-pi, pi) so no ray lies exactly on an axis.
    """
    elevation = np.radians(np.asarray(profile.elevation_deg, dtype=np.float64))
    azimuth = -np.pi + (np.arange(azimuth_bins) + 0.5) * (2 * np.pi / azimuth_bins)
    ce, se = np.cos(elevation)[:, None], np.sin(elevation)[:, None]
    d = np.stack(
        [ce * np.cos(azimuth), ce * np.sin(azimuth), np.broadcast_to(se, (len(se), azimuth_bins))],
        axis=-1,
    )
    return d, azimuth


def synthetic_scan(
    profile: SensorProfile, *, seed: int = 0, azimuth_bins: int | None = None
) -> SyntheticScan:
    """Ray-cast the street scene for every beam of `profile`.

    Intensity follows LISA's convention, stored intensity ~ rho * cos(incidence) (range
    compensated): rho from `lads.physics.materials` per label, cos from the analytic surface
    normal, times log-normal noise (sigma 5 %), encoded with `profile.intensity`. Ranges get
    Gaussian noise of `profile.range_accuracy_m`, clipped to the profile's range limits.
    Beams hitting nothing within [min_range_m, max_range_m] give no point.

    Args:
        profile: sensor whose elevation table and range/intensity specs are used.
        seed: seeds all noise; the same seed gives byte-identical output.
        azimuth_bins: beams per channel; default `profile.range_image_width`.

    Returns:
        SyntheticScan, points ordered by channel, then azimuth.

    Raises:
        ConfigError: azimuth_bins < 4.
    """
    bins = profile.range_image_width if azimuth_bins is None else int(azimuth_bins)
    if bins < 4:
        raise ConfigError(
            f"azimuth_bins={azimuth_bins}; expected an integer >= 4 (e.g. 1925 for a KITTI-like "
            "scan, or None for the profile's range_image_width)."
        )
    d, azimuth = beam_directions(profile, bins)
    hits = _cast_scene(d, azimuth)
    valid = (hits.t >= profile.min_range_m) & (hits.t <= profile.max_range_m)
    ring = np.broadcast_to(np.arange(d.shape[0])[:, None], valid.shape)[valid].astype(np.int64)
    dirs, labels = d[valid], hits.label[valid]
    cos_incidence = np.clip(np.abs(np.einsum("ij,ij->i", hits.normal[valid], dirs)), 0.0, 1.0)

    rng = np.random.default_rng(seed)
    range_noise = rng.normal(0.0, profile.range_accuracy_m, size=labels.size)
    range_m = np.clip(hits.t[valid] + range_noise, profile.min_range_m, profile.max_range_m)
    rho = np.asarray(reflectance_for_labels(labels, "semantickitti"), dtype=np.float64)
    reflectivity = rho * cos_incidence * rng.lognormal(0.0, INTENSITY_NOISE_SIGMA, labels.size)
    return SyntheticScan(
        xyz=(dirs * range_m[:, None]).astype(np.float32),
        intensity=profile.intensity.from_reflectivity(reflectivity),
        labels=labels.astype(np.uint32),
        ring=ring,
    )
