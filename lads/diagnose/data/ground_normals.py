"""Incidence on the ground from local ground planes rather than range-image neighbours.

Beyond ~20 m the rings of a spinning LiDAR meet the ground metres apart, so the image
neighbours of a ground point lie almost on one line (its own ring) and their PCA normal is
ill-conditioned: on SemanticKITTI scans thinned to 40k points the image normals of the
ground were a median 4-5 degrees off the full cloud's at 20-40 m, 18-19 at 40-80 m, the
local planes 0.5 and 0.9-1.3 (`python -m benchmarks.ground_incidence`). Road surfaces
are planar over metres, so a plane fitted to the ground points of a few metres around
each point spans several rings and gives the normal to about a degree
(docs/diagnose.md §5.1: normals from k-NN PCA *or the surface*; ill-conditioned ones excluded).
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import numpy.typing as npt

from lads.diagnose.config import CONFIG

TILE_M = CONFIG.table.local_ground_tile_m
MIN_POINTS = CONFIG.table.local_ground_min_points
MIN_SPREAD_M = CONFIG.table.local_ground_min_spread_m
MAX_TILT_DEG = CONFIG.table.local_ground_max_tilt_deg


def local_ground_cos(
    xyz: npt.NDArray[np.float64], ground: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Incidence cosine of each ground point against its local ground plane.

    Args:
        xyz: (N, 3) float64 coordinates in m, sensor at the origin.
        ground: (N,) bool, the points on the ground.

    Returns:
        cos (N,) float64 in [0, 1] (NaN where no plane was fitted) and ok (N,) bool: a ground
        point whose 3 x 3 tile support held MIN_POINTS well-spread points on a plane tilted
        at most MAX_TILT_DEG.
    """
    n = len(xyz)
    cos = np.full(n, np.nan)
    ok = np.zeros(n, dtype=bool)
    idx = np.flatnonzero(ground)
    if idx.size < MIN_POINTS:
        return cos, ok
    p = xyz[idx]
    a, b, good = _tile_planes(_support_moments(p))
    normal = np.stack([-a, -b, np.ones_like(a)], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    ray = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-9)
    c = np.abs(np.sum(ray * normal, axis=1))
    cos[idx[good]] = np.clip(c[good], 0.0, 1.0)
    ok[idx[good]] = True
    return cos, ok


def _support_moments(p: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(9, P) float64 sums (1, x, y, z, xx, xy, yy, xz, yz) over the ground points of each
    point's 3 x 3 support of TILE_M tiles (`p`: (P, 3) ground coordinates in m)."""
    cell = np.floor(p[:, :2] / TILE_M).astype(np.int64)
    lo = cell.min(axis=0) - 1
    cell -= lo
    shape = tuple(int(v) for v in cell.max(axis=0) + 2)
    flat = cell[:, 0] * shape[1] + cell[:, 1]
    # Moments of the plane's normal equations relative to each point's own tile centre would
    # differ between neighbours; the sensor origin is shared and |x| < 200 m keeps float64
    # sums exact enough.
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    terms = (np.ones_like(x), x, y, z, x * x, x * y, y * y, x * z, y * z)
    # np.bincount sums float64 weights in float64 (its stub says intp whatever the weights).
    moments = np.stack(
        [
            _box3(
                cast(
                    npt.NDArray[np.float64],
                    np.bincount(flat, weights=t, minlength=shape[0] * shape[1]),
                ).reshape(shape)
            )
            for t in terms
        ]
    )
    return moments[:, cell[:, 0], cell[:, 1]]


def _tile_planes(
    m: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """The least-squares plane z = a x + b y + c of each support from its (9, P) moments:
    a and b (P,) float64 (NaN or inf where singular), and good (P,) bool: at least MIN_POINTS
    points, a horizontal spread of at least MIN_SPREAD_M (standard deviation along the thinner
    axis) and a tilt of at most MAX_TILT_DEG."""
    count, sx, sy, sz, sxx, sxy, syy, sxz, syz = m
    with np.errstate(invalid="ignore", divide="ignore"):
        mx, my, mz = sx / count, sy / count, sz / count
        cxx = sxx / count - mx * mx
        cxy = sxy / count - mx * my
        cyy = syy / count - my * my
        cxz = sxz / count - mx * mz
        cyz = syz / count - my * mz
        det = cxx * cyy - cxy * cxy
        a = (cxz * cyy - cyz * cxy) / det
        b = (cyz * cxx - cxz * cxy) / det
    half_trace = 0.5 * (cxx + cyy)
    thin = half_trace - np.sqrt(np.maximum(half_trace**2 - det, 0.0))  # smaller eigenvalue
    good = (count >= MIN_POINTS) & (thin >= MIN_SPREAD_M**2) & np.isfinite(a) & np.isfinite(b)
    good &= np.hypot(a, b) <= math.tan(math.radians(MAX_TILT_DEG))
    return a, b, good


def _box3(grid: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Sum over each cell's 3 x 3 neighbourhood (zero outside the grid)."""
    padded = np.pad(grid, 1)
    out = np.zeros_like(grid)
    h, w = grid.shape
    for di in range(3):
        for dj in range(3):
            out += padded[di : di + h, dj : dj + w]
    return out
