"""Free-space carving of the cast's hits against the centre scan (docs/transfer.md §2).

A surfel can reach into space the centre scan saw through: the long ellipse of a car side
that a neighbouring scan met at grazing incidence, a disk at an edge that its scan took for
the inside of a surface. The centre scan's beams measure free space: a hit that lies clearly
in front of what each of the four centre beams around its direction measured is a surface
the centre scan would have seen, and did not. Such hits take no part in the blend, so the
target beam takes the surface behind. Where any of the four beams returned nothing, free
space is unknown there and nothing is carved; a hit on a surface a centre beam did see lies
at that beam's range, not in front of it. One compiled pass over the target's beams gives
each beam the distance below which its hits are carved (`carve_floor`).

A target ray that runs within one beam divergence of a centre beam shares that beam's
footprint: the centre return says the footprint was free up to the surface it hit. A hit
clearly in front of that surface's plane along the ray is carved too, although a neighbouring
centre beam may have met something nearer (an object's silhouette between the two beams).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

from lads.sensors.lookup import nearest_entry
from lads.sensors.profile import SensorProfile
from lads.transfer.bounds import coarse_atan2

F64 = npt.NDArray[np.float64]
# The target's beams for the compiled passes: cos and sin of its elevations and azimuths,
# then the (3, 3) turn and (3,) shift from the target frame to the centre scan's.
Beams = tuple[F64, F64, F64, F64, F64, F64]
# A hit is carved when every centre beam around it measured farther than its range times
# (1 + CARVE_SHARE) plus CARVE_NOISE_SIGMAS times the source's range accuracy: a return may lie
# a few sigma beyond the surface it hit. The share was chosen on the validation streets by
# Chamfer distance (benchmarks/sensor_transfer.py) among 0, 0.5, 1 and 2 %: without it a
# stopped vehicle's transfer starts to lose real surfaces.
CARVE_SHARE = 0.005
CARVE_NOISE_SIGMAS = 3.0
# A centre return's plane bounds a target ray's free space only where the ray meets the plane
# at |cos| >= this (a grazing plane's crossing moves far with a small normal error). Chosen on
# the validation streets between this and the surfels' own MIN_COS (0.05) by Chamfer
# distance, with the footprint of one whole divergence (benchmarks/sensor_transfer.py).
FOOTPRINT_MIN_COS = 0.2


@dataclass(frozen=True, slots=True)
class FreeSpace:
    """What the centre scan saw, on its own beam grid.

    Attributes:
        range_m: (Hs, Ws) float64 nearest return of each source beam, m; inf: none.
        elevation_rad: (Hs,) ascending source beam elevations, radians.
        to_source: (4, 4) float64 target frame -> centre scan frame.
        margin_m: CARVE_NOISE_SIGMAS x the source's range accuracy, m.
        point_m, normal: (Hs, Ws, 3) float64 the nearest return of each beam and its unit
            normal (NaN: none), or None: no footprint rule.
        footprint_rad: a target ray within this angle of a centre return's direction shares
            its beam's footprint (the source's full beam divergence).
    """

    range_m: F64
    elevation_rad: F64
    to_source: F64
    margin_m: float
    point_m: F64 | None = None
    normal: F64 | None = None
    footprint_rad: float = 0.0


def free_space(
    xyz: npt.ArrayLike,
    source: SensorProfile,
    to_source: npt.ArrayLike,
    normal: npt.ArrayLike | None = None,
) -> FreeSpace:
    """The centre scan's (N, 3) points (its own frame, m) on a grid of its sensor's beams:
    rows by the nearest table elevation, `range_image_width` equal azimuth bins from -pi;
    with their (N, 3) unit `normal`, the footprint rule as well (module doc)."""
    table = np.sort(np.radians(np.asarray(source.elevation_deg, dtype=np.float64)))
    points = np.ascontiguousarray(np.asarray(xyz, dtype=np.float64).reshape(-1, 3))
    normals = np.full_like(points, np.nan) if normal is None else np.asarray(normal, np.float64)
    image, point_m, normal_img = _binned(
        points, np.ascontiguousarray(normals.reshape(-1, 3)), table, int(source.range_image_width)
    )
    margin = CARVE_NOISE_SIGMAS * source.range_accuracy_m
    to = np.asarray(to_source, dtype=np.float64)
    if normal is None:
        return FreeSpace(image, table, to, margin)
    return FreeSpace(image, table, to, margin, point_m, normal_img, source.beam_divergence_rad)


@numba.njit(cache=True, nogil=True, inline="always")
def _cell(x: float, y: float, z: float, table: F64, columns: int) -> tuple[int, int]:
    """The (nearest elevation row, azimuth bin from -pi) cell of direction (x, y, z) on the
    centre scan's grid. A cell only bins the scan: the coarse angles (error 1e-5 rad) do."""
    k = nearest_entry(table, coarse_atan2(z, math.sqrt(x * x + y * y)))
    j = int(math.floor((coarse_atan2(y, x) + math.pi) / (2.0 * math.pi / columns))) % columns
    return k, j


@numba.njit(cache=True, nogil=True)
def _binned(points: F64, normal: F64, table: F64, columns: int) -> tuple[F64, F64, F64]:
    """(H, W) nearest range of the points in each (nearest elevation, azimuth bin) cell, and
    (H, W, 3) that point and its normal (NaN where the cell is empty)."""
    rows = table.shape[0]
    image = np.full((rows, columns), np.inf)
    point_m = np.full((rows, columns, 3), np.nan)
    normal_img = np.full((rows, columns, 3), np.nan)
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        r = math.sqrt(x * x + y * y + z * z)
        if not (r > 0.0 and r < math.inf):
            continue
        k, j = _cell(x, y, z, table, columns)
        if r < image[k, j]:
            image[k, j] = r
            for a in range(3):
                point_m[k, j, a] = points[i, a]
                normal_img[k, j, a] = normal[i, a]
    return image, point_m, normal_img


def carved(
    space: FreeSpace | None,
    best: F64,
    best_cos: F64,
    hits: tuple[npt.NDArray[np.int64], F64, F64],
    elevation_rad: F64,
    azimuth_rad: F64,
) -> tuple[F64, F64, F64]:
    """The cast's (H, W) nearest hit distance and |cos| once the hits (beam, distance, |cos|)
    in the centre scan's free space are left out, and the (H, W) floor below which they lie
    (`carve_floor`; all 0 without `space`, and then `best`, `best_cos` come back as given)."""
    floor = np.zeros_like(best)
    if space is None:
        return best, best_cos, floor
    floor = carve_floor(space, best, elevation_rad, azimuth_rad)
    if not floor.any():
        return best, best_cos, floor
    near, near_cos = nearest_hits(hits[0], hits[1], hits[2], floor)
    return near, near_cos, floor


def carve_floor(space: FreeSpace, best: F64, elevation_rad: F64, azimuth_rad: F64) -> F64:
    """(H, W) distance below which a target beam's hits lie in the centre scan's free space
    (0: none carved), from each beam's nearest hit `best` (inf: none).

    Whether a point on a beam is carved depends on its distance only, and monotonically: the
    four centre beams around it are the same all along a beam from the centre scan's origin,
    and a nearer point clears their ranges by more. So one test per beam, at its nearest
    hit, gives the bound for all of its hits. (A target mounted off the source's origin sees
    the four beams shift slightly along its beam; the bound is taken where the nearest hit
    lies.) The footprint rule's bound, the plane's crossing, is one distance per beam too."""
    m = np.ascontiguousarray(space.to_source)
    beams = (
        np.cos(elevation_rad),
        np.sin(elevation_rad),
        np.cos(azimuth_rad),
        np.sin(azimuth_rad),
        np.ascontiguousarray(m[:3, :3]),
        np.ascontiguousarray(m[:3, 3]),
    )
    floor = _floor(best, beams, space.range_m, space.elevation_rad, space.margin_m, CARVE_SHARE)
    if space.point_m is None or space.normal is None:
        return floor
    return _footprint_floor(
        best,
        beams,
        space.point_m,
        space.normal,
        space.elevation_rad,
        space.footprint_rad,
        space.margin_m,
        CARVE_SHARE,
        floor,
    )


@numba.njit(cache=True, nogil=True)
def _floor(
    best: F64,
    beams: Beams,
    image: F64,
    table: F64,
    margin_m: float,
    share: float,
) -> F64:
    """`carve_floor` in one pass over the beams; scalars inside the loop."""
    cos_el, sin_el, cos_az, sin_az, turn, shift = beams
    rows, columns = best.shape
    rows_s, cols_s = image.shape
    step_s = 2.0 * math.pi / cols_s
    floor = np.zeros((rows, columns))
    for k in range(rows):
        for j in range(columns):
            t = best[k, j]
            if not t < math.inf:
                continue
            px, py, pz = t * cos_el[k] * cos_az[j], t * cos_el[k] * sin_az[j], t * sin_el[k]
            qx = turn[0, 0] * px + turn[0, 1] * py + turn[0, 2] * pz + shift[0]
            qy = turn[1, 0] * px + turn[1, 1] * py + turn[1, 2] * pz + shift[1]
            qz = turn[2, 0] * px + turn[2, 1] * py + turn[2, 2] * pz + shift[2]
            horizontal = math.sqrt(qx * qx + qy * qy)
            above = int(np.searchsorted(table, coarse_atan2(qz, horizontal)))
            if above <= 0 or above >= rows_s:
                continue  # outside the centre scan's rows: nothing was measured there
            c = (coarse_atan2(qy, qx) + math.pi) / step_s - 0.5
            j0 = int(math.floor(c)) % cols_s
            j1 = (j0 + 1) % cols_s
            a, b = image[above - 1, j0], image[above - 1, j1]
            c, d = image[above, j0], image[above, j1]
            if not max(max(a, b), max(c, d)) < math.inf:
                continue  # a beam without a return: free space unknown
            seen = min(min(a, b), min(c, d))
            bound = (seen - margin_m) / (1.0 + share)
            r = math.sqrt(horizontal * horizontal + qz * qz)
            if r < bound:
                floor[k, j] = t + (bound - r)
    return floor


@numba.njit(cache=True, nogil=True)
def _footprint_floor(
    best: F64,
    beams: Beams,
    point_m: F64,
    normal: F64,
    table: F64,
    footprint_rad: float,
    margin_m: float,
    share: float,
    floor: F64,
) -> F64:
    """`floor` raised, in place, where a beam's nearest hit lies in front of the plane of the
    centre return whose footprint the beam shares (module doc); scalars inside the loop."""
    cos_el, sin_el, cos_az, sin_az, turn, shift = beams
    rows, columns = best.shape
    cols_s = point_m.shape[1]
    for k in range(rows):
        for j in range(columns):
            t = best[k, j]
            if not t < math.inf:
                continue
            ux, uy, uz = cos_el[k] * cos_az[j], cos_el[k] * sin_az[j], sin_el[k]
            dx = turn[0, 0] * ux + turn[0, 1] * uy + turn[0, 2] * uz
            dy = turn[1, 0] * ux + turn[1, 1] * uy + turn[1, 2] * uz
            dz = turn[2, 0] * ux + turn[2, 1] * uy + turn[2, 2] * uz
            px, py, pz = shift[0] + t * dx, shift[1] + t * dy, shift[2] + t * dz
            ks, js = _cell(px, py, pz, table, cols_s)
            if math.isnan(point_m[ks, js, 0]) or math.isnan(normal[ks, js, 0]):
                continue
            qx, qy, qz = point_m[ks, js, 0], point_m[ks, js, 1], point_m[ks, js, 2]
            # Inside that beam's footprint: the hit's and the return's directions from the
            # centre scan's origin (a target mounted elsewhere looks along other lines).
            pq = math.sqrt((qx * qx + qy * qy + qz * qz) * (px * px + py * py + pz * pz))
            if math.acos(min(1.0, (qx * px + qy * py + qz * pz) / pq)) > footprint_rad:
                continue
            nx, ny, nz = normal[ks, js, 0], normal[ks, js, 1], normal[ks, js, 2]
            across = nx * dx + ny * dy + nz * dz
            if abs(across) < FOOTPRINT_MIN_COS:
                continue
            crossing = (nx * (qx - shift[0]) + ny * (qy - shift[1]) + nz * (qz - shift[2])) / across
            bound = crossing * (1.0 - share) - margin_m
            if t < bound and bound > floor[k, j]:
                floor[k, j] = bound
    return floor


@numba.njit(cache=True, nogil=True)
def nearest_hits(
    hit_pix: npt.NDArray[np.int64], hit_t: F64, hit_cos: F64, floor: F64
) -> tuple[F64, F64]:
    """(H, W) nearest hit distance at or beyond each beam's `floor` (inf: none) and its
    |cos| (1: none), over the hits in order: the cast's pass 1 rule, so with a zero floor the
    same hits give the same arrays."""
    rows, columns = floor.shape
    best = np.full((rows, columns), np.inf)
    best_cos = np.ones((rows, columns))
    for h in range(hit_pix.shape[0]):
        k = hit_pix[h] // columns
        j = hit_pix[h] - k * columns
        t = hit_t[h]
        if t >= floor[k, j] and t < best[k, j]:
            best[k, j] = t
            best_cos[k, j] = hit_cos[h]
    return best, best_cos
