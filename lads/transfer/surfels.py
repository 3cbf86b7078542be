"""A surfel scene model from scans and poses (docs/transfer.md §1).

Every return of a source scan becomes a surfel: a small ellipse in the surface's plane,
centred on the return, that covers the patch the source beam sampled. Its normal comes from
the scan's own range image (neighbouring rings and azimuths); its two conjugate semi-axes are
the source's azimuth step and ring gap at that range, projected along the beam onto the plane
(so they stretch by 1 / cos on oblique surfaces), times a share. An ellipse, not a disk: a
32-ring scan's rings lie four times farther apart than its azimuth samples, and a disk as wide
as the ring gap fattens every object's edges sideways. A surfel keeps the return's label and
the surface's albedo (its reflectivity divided by the source's cos of incidence). Surfels of
several scans, moved into one frame with their poses, are the scene a target sensor is
ray-cast against (`lads.transfer.cast`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numba
import numpy as np
import numpy.typing as npt

from lads.physics.image_kernels import image_normals
from lads.physics.modalities import DEFAULT_MAX_DEPTH_JUMP, MAX_COLUMN_GAP
from lads.physics.projection import MIN_RANGE_M, RangeImage, channels_of, organise
from lads.sensors.profile import SensorProfile

# Semi-axes of a surfel as a share of its beam cell (azimuth step by ring gap, at its range),
# and the incidence cosine below which its stretching on oblique surfaces stops (a grazing
# patch is long along the beam, but a longer ellipse reaches across edges it never sampled).
# The share is at least 1 / sqrt(2), so one scan tiles a surface by itself (a stopped vehicle's
# window adds no new samples); both values chosen on validation streets by Chamfer distance
# (benchmarks/sensor_transfer.py).
RADIUS_SHARE = 0.75
MIN_COS = 0.05
# Share of the beam cell at a silhouette, along the axis where the next return of the scan
# lies behind (the object's edge lies anywhere in the gap, half-way on average):
# a full share there fattens every object by the part of the gap it never reached. Chosen
# on validation streets with the shares above (benchmarks/sensor_transfer.py; 0.6 and 0.5
# tie within a hundredth of a millimetre of mean Chamfer distance there).
EDGE_SHARE = 0.6
# Floor of the cos an albedo is divided by (against division by zero only).
ALBEDO_MIN_COS = 0.02
F64 = npt.NDArray[np.float64]
# (cos of incidence, range m) -> the least albedo a return the source detected can have:
# the source's detection limit says more than a stored intensity below its encoding's step.
DetectionFloor = Callable[[F64, F64], F64]


def profile_floor(profile: SensorProfile) -> DetectionFloor:
    """The least albedo the sensor's median detection implies: albedo cos / R^2 reaches its
    detection limit P_lim (`detection` of the profile, docs/physics.md §9.7)."""
    limit = profile.detection.power

    def least(cos: F64, range_m: F64) -> F64:
        return limit * range_m * range_m / np.maximum(cos, ALBEDO_MIN_COS)

    return least


@dataclass(frozen=True, slots=True)
class SurfelShape:
    """How large surfels are: `radius_share` of the beam cell (`edge_share` along an axis
    that ends at a silhouette), stretched on oblique surfaces down to an incidence cosine of
    `min_cos`."""

    radius_share: float = RADIUS_SHARE
    min_cos: float = MIN_COS
    edge_share: float = EDGE_SHARE


DEFAULT_SHAPE = SurfelShape()


@dataclass(frozen=True, slots=True)
class Surfels:
    """Disks of one or more scans in one frame.

    Attributes:
        centre: (M, 3) float64 disk centres, m.
        normal: (M, 3) float64 unit normals, facing the sensor that saw them.
        axis_a, axis_b: (M, 3) float64 conjugate semi-axes of the ellipse in its plane, m
            (along the source's azimuth and elevation steps).
        radius_m: (M,) float64 a radius that bounds the ellipse (|axis_a| + |axis_b|), m.
        label: (M,) uint32 stored label of the source return (0 when unlabelled).
        albedo: (M,) float64 reflectivity / cos(incidence) of the surface, unitless.
        least_albedo: (M,) float64 the least albedo the source's detection of the return
            implies (`DetectionFloor`): far, grazing returns store an intensity at or below
            the encoding's step, but were strong enough to be detected.
        weight: (M,) float64 how much the albedo is to be trusted: the source's cos^2 of
            incidence (1 for retro-reflectors), the weight of a least-squares albedo.
        retro: (M,) bool, a retro-reflector (returns as much at any incidence).
        point: (M,) int64 row of the source return in its scan file.
        moving: (M,) bool, of a class of things that move (`moving` in materials.yaml): a
            neighbouring scan does not lend it.
        instances: the scan's instances and their centroids (`Instances`), or None when the
            labels carry no instance ids.
    """

    centre: F64
    normal: F64
    axis_a: F64
    axis_b: F64
    radius_m: F64
    label: npt.NDArray[np.uint32]
    albedo: F64
    least_albedo: F64
    weight: F64
    retro: npt.NDArray[np.bool_]
    point: npt.NDArray[np.int64]
    moving: npt.NDArray[np.bool_]
    instances: Instances | None = None

    def __len__(self) -> int:
        return int(self.centre.shape[0])

    def take(self, keep: npt.NDArray[np.bool_] | npt.NDArray[np.int64]) -> Surfels:
        """The surfels selected by a mask or index array (their instances counted again)."""
        fields = [getattr(self, f)[keep] for f in self.__slots__ if f != "instances"]
        out = Surfels(*fields)  # type: ignore[arg-type]
        return out if self.instances is None else out.with_instances()

    def with_instances(self) -> Surfels:
        """These surfels with their `Instances` (labels whose upper 16 bits are an id)."""
        return replace(self, instances=Instances.of(self.label, self.centre))


@dataclass(frozen=True, slots=True)
class Instances:
    """The instances among a scan's surfels, counted once per scan (every window that holds
    the scan compares them with its centre scan's).

    Attributes:
        ids: (L,) int64 increasing instance ids > 0 (a label's upper 16 bits; 0 is none).
        centre_m: (L, 3) float64 centroid of each instance's surfels, m, scan frame.
    """

    ids: npt.NDArray[np.int64]
    centre_m: F64

    @staticmethod
    def of(label: npt.NDArray[np.uint32], centre: F64) -> Instances:
        """From (M,) uint32 labels and (M, 3) surfel centres in m."""
        ids = (label >> np.uint32(16)).astype(np.int64)
        some = np.flatnonzero(ids)
        ids, xyz = ids[some], centre[some]
        n = np.bincount(ids, minlength=1)
        present = np.flatnonzero(n)
        present = present[present > 0]
        sums = np.stack([np.bincount(ids, weights=xyz[:, a])[present] for a in range(3)], axis=1)
        return Instances(present, sums / n[present][:, None])


def scan_surfels(
    xyz: npt.ArrayLike,
    reflectivity: npt.ArrayLike,
    profile: SensorProfile,
    *,
    labels: npt.ArrayLike | None = None,
    retro: npt.ArrayLike | None = None,
    moving: npt.ArrayLike | None = None,
    ring: npt.ArrayLike | None = None,
    shape: SurfelShape = DEFAULT_SHAPE,
    floor: DetectionFloor | None = None,
) -> Surfels:
    """The surfels of one scan, in its sensor frame.

    Args:
        xyz: (N, 3) coordinates in m, sensor frame. Returns at zero range (lost beams) give
            no surfel.
        reflectivity: (N,) linear reflectivity of each return (the encoding's
            `to_reflectivity` of the stored intensity).
        profile: the source sensor (elevations, range image width).
        labels: (N,) stored labels, or None.
        retro, moving: (N,) bool, returns of retro-reflectors (their albedo is not divided by
            cos) and of things that move (only their own scan shows them), or None.
        ring: (N,) channel per point, or None to take the nearest elevation.
        shape: `SurfelShape`.
        floor: the source's detection floor; default `profile_floor(profile)`.

    Returns:
        Surfels, one per return beyond MIN_RANGE_M, in file order.
    """
    xyz64 = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    r = np.sqrt(np.einsum("ij,ij->i", xyz64, xyz64))
    valid = np.flatnonzero(r > MIN_RANGE_M)
    pts, rng_m = xyz64[valid], r[valid]
    chan = channels_of(pts, profile, None if ring is None else np.asarray(ring)[valid])
    view, image, normal, cos_raw = _geometry(pts, rng_m, chan, profile)
    cos = np.clip(cos_raw, shape.min_cos, 1.0)
    axis_a, axis_b = _cell_axes(pts, rng_m, view, normal, cos, profile, chan, shape.radius_share)
    if shape.edge_share != shape.radius_share:
        _shrink_at_silhouettes(axis_a, axis_b, image, rng_m, shape, pts, normal)
    radius = np.linalg.norm(axis_a, axis=1) + np.linalg.norm(axis_b, axis=1)
    refl = np.asarray(reflectivity, dtype=np.float64)[valid]
    is_retro = _flags(retro, len(r))[valid]
    albedo, weight = _albedo(refl, cos_raw, is_retro)
    least = (floor or profile_floor(profile))(np.where(is_retro, 1.0, cos_raw), rng_m)
    lab = np.zeros(len(pts), np.uint32) if labels is None else np.asarray(labels)[valid]
    return Surfels(
        pts,
        normal,
        axis_a,
        axis_b,
        radius,
        lab.astype(np.uint32),
        albedo,
        least,
        weight,
        is_retro,
        valid.astype(np.int64),
        _flags(moving, len(r))[valid],
    )


def _flags(values: npt.ArrayLike | None, n: int) -> npt.NDArray[np.bool_]:
    """(n,) bool of `values`, all False for None."""
    return np.zeros(n, bool) if values is None else np.asarray(values, bool)


def _albedo(refl: F64, cos_raw: F64, retro: npt.NDArray[np.bool_]) -> tuple[F64, F64]:
    """(N,) albedo (reflectivity / cos of incidence; a retro-reflector's reflectivity) and the
    trust in it (cos^2; 1 for a retro-reflector). The target multiplies by its own cos of the
    same normal: dividing by the same raw cos here (floored only against division by zero)
    keeps the two estimates' errors cancelling."""
    c = np.clip(cos_raw, ALBEDO_MIN_COS, 1.0)
    return np.where(retro, refl, refl / c), np.where(retro, 1.0, c * c)


def _geometry(
    pts: F64, range_m: F64, chan: npt.NDArray[np.int64], profile: SensorProfile
) -> tuple[F64, RangeImage, F64, F64]:
    """(N, 3) unit view directions, the scan's range image, (N, 3) unit normals facing the
    sensor and (N,) the raw cos of incidence (normal against view, may be < 0.02)."""
    view = pts / range_m[:, None]
    image = organise(pts, range_m, chan, profile.channels, profile.range_image_width)
    normal = _normals(pts, view, image)
    return view, image, normal, -np.einsum("ij,ij->i", normal, view)


def _shrink_at_silhouettes(
    axis_a: F64,
    axis_b: F64,
    image: RangeImage,
    range_m: F64,
    shape: SurfelShape,
    pts: F64,
    normal: F64,
) -> None:
    """Scale, in place, each (N, 3) semi-axis that ends at a silhouette (`silhouette_sides`
    of the scan's range image) from `shape.radius_share` of the cell to `shape.edge_share`."""
    edge_a, edge_b = silhouette_sides(
        image.range_m.astype(np.float64),
        image.index,
        image.row,
        image.col,
        range_m,
        DEFAULT_MAX_DEPTH_JUMP,
        MAX_COLUMN_GAP,
        pts,
        normal,
    )
    axis_a[edge_a] *= shape.edge_share / shape.radius_share
    axis_b[edge_b] *= shape.edge_share / shape.radius_share


def _normals(pts: F64, view: F64, image: RangeImage) -> F64:
    """(N, 3) unit normals facing the sensor, from the scan's range image; a return that
    does not own its pixel or has no usable neighbourhood gets the view direction reversed
    (a disk facing the sensor)."""
    raw, ok = image_normals(
        image.xyz.astype(np.float64),
        image.range_m.astype(np.float64),
        image.index >= 0,
        MAX_COLUMN_GAP,
        DEFAULT_MAX_DEPTH_JUMP,
        rows_by_line=True,
    )
    return _facing(raw, ok, image.index, image.row, image.col, view)


@numba.njit(cache=True, nogil=True)
def _facing(
    raw: F64,
    ok: npt.NDArray[np.bool_],
    index: npt.NDArray[np.int64],
    row: npt.NDArray[np.int64],
    col: npt.NDArray[np.int64],
    view: F64,
) -> F64:
    """(N, 3) each return's unit normal from its pixel's (H, W, 3) unnormalised `raw` one,
    turned to face the sensor (against the (N, 3) unit view); -view where the return does not
    own its pixel or the pixel has none (`ok` false)."""
    n = view.shape[0]
    normal = np.empty((n, 3))
    for i in range(n):
        v, u = row[i], col[i]
        if index[v, u] != i or not ok[v, u]:
            for k in range(3):
                normal[i, k] = -view[i, k]
            continue
        x, y, z = raw[v, u, 0], raw[v, u, 1], raw[v, u, 2]
        length = math.sqrt(x * x + y * y + z * z)
        x, y, z = x / length, y / length, z / length
        if x * view[i, 0] + y * view[i, 1] + z * view[i, 2] > 0:
            x, y, z = -x, -y, -z
        normal[i, 0], normal[i, 1], normal[i, 2] = x, y, z
    return normal


def _cell_axes(
    pts: F64,
    r: F64,
    view: F64,
    normal: F64,
    cos: F64,
    profile: SensorProfile,
    chan: npt.NDArray[np.int64],
    share: float,
) -> tuple[F64, F64]:
    """(N, 3) each: the azimuth step and the ring gap of each return's beam cell at its range,
    projected along the beam onto its plane, times `share`."""
    el = np.radians(np.asarray(profile.elevation_deg, dtype=np.float64))
    gaps = np.diff(el)
    below = np.concatenate([[gaps[0]], gaps])
    above = np.concatenate([gaps, [gaps[-1]]])
    d_el = np.maximum(below, above)[chan]
    d_az = 2.0 * np.pi / profile.range_image_width
    return _projected_steps(pts, r, view, normal, cos, d_el, d_az, share)


@numba.njit(cache=True, nogil=True)
def _projected_steps(
    pts: F64, r: F64, view: F64, normal: F64, cos: F64, d_el: F64, d_az: float, share: float
) -> tuple[F64, F64]:
    """`_cell_axes` per return: the steps east (azimuth) and up (elevation, view x east) of
    share x range x the angular step, moved along the beam onto the plane: x - v (n.x) / cos,
    where the beam's neighbour would meet it (cos: the clipped incidence)."""
    n = pts.shape[0]
    axis_a = np.empty((n, 3))
    axis_b = np.empty((n, 3))
    for i in range(n):
        horiz = max(math.hypot(pts[i, 0], pts[i, 1]), 1e-9)
        ex, ey = -pts[i, 1] / horiz, pts[i, 0] / horiz
        vx, vy, vz = view[i, 0], view[i, 1], view[i, 2]
        ux, uy, uz = -vz * ey, vz * ex, vx * ey - vy * ex  # view x east (east has no z)
        scale = share * r[i]
        sa, sb = scale * d_az, scale * d_el[i]
        ax, ay, az = ex * sa, ey * sa, 0.0 * sa
        bx, by, bz = ux * sb, uy * sb, uz * sb
        nx, ny, nz = normal[i, 0], normal[i, 1], normal[i, 2]
        # In numpy's einsum order, so the axes come out to the bit as they did from it.
        along_a = ((nx * ax + nz * az) + ny * ay) / cos[i]
        along_b = ((nx * bx + nz * bz) + ny * by) / cos[i]
        axis_a[i, 0], axis_a[i, 1], axis_a[i, 2] = (
            ax + vx * along_a,
            ay + vy * along_a,
            az + vz * along_a,
        )
        axis_b[i, 0], axis_b[i, 1], axis_b[i, 2] = (
            bx + vx * along_b,
            by + vy * along_b,
            bz + vz * along_b,
        )
    return axis_a, axis_b


@numba.njit(cache=True, nogil=True)
def silhouette_sides(
    range_img: F64,
    index: npt.NDArray[np.int64],
    row: npt.NDArray[np.int64],
    col: npt.NDArray[np.int64],
    range_m: F64,
    max_depth_jump: float,
    max_column_gap: int,
    pts: F64,
    normal: F64,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """Per return, whether its surface ends next to it along azimuth (first array) and along
    elevation (second): on one side the nearest return of the scan (the adjacent row; the
    nearest occupied column within `max_column_gap`) lies more than `max_depth_jump` x its
    range behind it and off the return's plane (`_off_plane`: far ground, whose rings lie
    metres apart, goes on). A missing neighbour is no silhouette: real scans drop returns of
    dark or wet surfaces, and shrinking the surfels around every dropout leaves holes.

    Args:
        range_img: (H, W) range of each pixel's owner in m, index: (H, W) its row, -1 empty.
        row, col: (N,) pixel of each return; range_m: (N,) its range in m.
        pts, normal: (N, 3) each return's point in m and its unit normal.
    """
    height, width = index.shape
    n = row.shape[0]
    edge_a = np.zeros(n, dtype=np.bool_)
    edge_b = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        far = range_m[i] * (1.0 + max_depth_jump)
        for sign in (-1, 1):
            v = row[i] + sign
            if 0 <= v < height and index[v, col[i]] >= 0 and range_img[v, col[i]] > far:
                j = index[v, col[i]]
                edge_b[i] = edge_b[i] or _off_plane(pts, normal, i, j, max_depth_jump)
            for step in range(1, max_column_gap + 1):
                u = (col[i] + sign * step) % width
                j = index[row[i], u]
                if j >= 0:
                    if range_img[row[i], u] > far:
                        edge_a[i] = edge_a[i] or _off_plane(pts, normal, i, j, max_depth_jump)
                    break
    return edge_a, edge_b


@numba.njit(cache=True, nogil=True, inline="always")
def _off_plane(pts: F64, normal: F64, i: int, j: int, max_depth_jump: float) -> bool:
    """Whether return j's beam meets return i's plane more than max_depth_jump x its range
    away from it: |n.(p_j - p_i)| > jump r_j |n.d_j| (d_j its unit direction)."""
    dx, dy, dz = pts[j, 0] - pts[i, 0], pts[j, 1] - pts[i, 1], pts[j, 2] - pts[i, 2]
    off = abs(normal[i, 0] * dx + normal[i, 1] * dy + normal[i, 2] * dz)
    along = abs(normal[i, 0] * pts[j, 0] + normal[i, 1] * pts[j, 1] + normal[i, 2] * pts[j, 2])
    return off > max_depth_jump * along  # r_j |n.d_j| = |n.p_j|
