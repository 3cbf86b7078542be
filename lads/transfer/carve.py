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
# A hit is carved when every centre beam around it measured farther than its range times
# (1 + CARVE_SHARE) plus CARVE_NOISE_SIGMAS times the source's range accuracy: a return may lie
# a few sigma beyond the surface it hit. The share was chosen on the validation streets by
# Chamfer distance (benchmarks/sensor_transfer.py) among 0, 0.5, 1 and 2 %: without it a
# stopped vehicle's transfer starts to lose real surfaces.
CARVE_SHARE = 0.005
CARVE_NOISE_SIGMAS = 3.0


@dataclass(frozen=True, slots=True)
class FreeSpace:
    """What the centre scan saw, on its own beam grid.

    Attributes:
        range_m: (Hs, Ws) float64 nearest return of each source beam, m; inf: none.
        elevation_rad: (Hs,) ascending source beam elevations, radians.
        to_source: (4, 4) float64 target frame -> centre scan frame.
        margin_m: CARVE_NOISE_SIGMAS x the source's range accuracy, m.
    """

    range_m: F64
    elevation_rad: F64
    to_source: F64
    margin_m: float


def free_space(xyz: npt.ArrayLike, source: SensorProfile, to_source: npt.ArrayLike) -> FreeSpace:
    """The centre scan's (N, 3) points (its own frame, m) on a grid of its sensor's beams:
    rows by the nearest table elevation, `range_image_width` equal azimuth bins from -pi."""
    table = np.sort(np.radians(np.asarray(source.elevation_deg, dtype=np.float64)))
    points = np.ascontiguousarray(np.asarray(xyz, dtype=np.float64).reshape(-1, 3))
    image = _binned(points, table, int(source.range_image_width))
    margin = CARVE_NOISE_SIGMAS * source.range_accuracy_m
    return FreeSpace(image, table, np.asarray(to_source, dtype=np.float64), margin)


@numba.njit(cache=True, nogil=True)
def _binned(points: F64, table: F64, columns: int) -> F64:
    """(H, W) nearest range of the points in each (nearest elevation, azimuth bin) cell."""
    rows = table.shape[0]
    image = np.full((rows, columns), np.inf)
    step = 2.0 * math.pi / columns
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        r = math.sqrt(x * x + y * y + z * z)
        if not (r > 0.0 and r < math.inf):
            continue
        # A cell only bins the scan: the coarse angles (error 1e-5 rad) do.
        k = nearest_entry(table, coarse_atan2(z, math.sqrt(x * x + y * y)))
        j = int(math.floor((coarse_atan2(y, x) + math.pi) / step)) % columns
        if r < image[k, j]:
            image[k, j] = r
    return image


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
    lies.)"""
    m = np.ascontiguousarray(space.to_source)
    return _floor(
        best,
        np.cos(elevation_rad),
        np.sin(elevation_rad),
        np.cos(azimuth_rad),
        np.sin(azimuth_rad),
        np.ascontiguousarray(m[:3, :3]),
        np.ascontiguousarray(m[:3, 3]),
        space.range_m,
        space.elevation_rad,
        space.margin_m,
        CARVE_SHARE,
    )


@numba.njit(cache=True, nogil=True)
def _floor(
    best: F64,
    cos_el: F64,
    sin_el: F64,
    cos_az: F64,
    sin_az: F64,
    turn: F64,
    shift: F64,
    image: F64,
    table: F64,
    margin_m: float,
    share: float,
) -> F64:
    """`carve_floor` in one pass over the beams; scalars inside the loop."""
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
