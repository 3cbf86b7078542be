"""Which points are ground, from geometry alone: for scans without point labels (detection
data), so that wet ground has a road to lie on (docs/augment.md §2).

Method. The xy plane is cut into square cells. A cell's lowest point is a ground candidate
when it lies near the ground height h0 expected at its distance d, h0 + d * max_slope
(h0: the median of the lowest points of the cells within NEAR_RANGE_M, which are ground in
any street scan). A point is ground when its cell, or a neighbouring cell, is a candidate
and the point lies within `height_tol_m` above that cell's lowest point. The neighbours keep
the edge of a cell under a car's overhang: a car's lowest point sits well above the road, so
its cells are no candidates and its body is never ground.

The defaults were chosen on validation frames from a fixed grid (`python -m
benchmarks.ground_fit`; benchmarks/results/ground_fit.json names the frames and gives the
scores on places and a sensor they never saw).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit

from lads.physics.projection import MIN_RANGE_M

# Cells whose lowest point sets the reference ground height: near the sensor, where a street
# scan always sees road (m, horizontal distance).
NEAR_RANGE_M = (3.0, 15.0)
# Points farther than this from the sensor along x or y are never ground: it bounds the grid
# (m; beyond every shipped sensor's range).
EXTENT_M = 250.0


@dataclass(frozen=True, slots=True)
class GroundFit:
    """The settings of `ground_mask`.

    Attributes:
        cell_m: side of the square xy cells, m.
        height_tol_m: how far above its cell's lowest point a point may lie and be ground, m.
        max_slope: how much the ground may rise per metre of distance from the sensor.
    """

    cell_m: float = 1.0
    height_tol_m: float = 0.15
    max_slope: float = 0.02


def ground_mask(
    xyz: npt.NDArray[np.floating[Any]], fit: GroundFit = GroundFit()
) -> npt.NDArray[np.bool_]:
    """(N,) bool: the points that lie on the ground (see the module docstring).

    Args:
        xyz: (N, 3) points in the sensor frame, m, z up. Rows at zero range (within
            MIN_RANGE_M), and points beyond EXTENT_M horizontally, are never ground.
        fit: the settings.
    """
    p = np.asarray(xyz, dtype=np.float64)
    valid = (
        np.isfinite(p).all(axis=1)
        & (np.einsum("ij,ij->i", p, p) > MIN_RANGE_M**2)
        & (np.abs(p[:, 0]) < EXTENT_M)
        & (np.abs(p[:, 1]) < EXTENT_M)
    )
    if not valid.any():
        return np.zeros(p.shape[0], dtype=bool)
    cx = np.floor(np.where(valid, p[:, 0], 0.0) / fit.cell_m).astype(np.int64)
    cy = np.floor(np.where(valid, p[:, 1], 0.0) / fit.cell_m).astype(np.int64)
    x0, y0 = int(cx[valid].min()), int(cy[valid].min())
    shape = (int(cx[valid].max()) - x0 + 1, int(cy[valid].max()) - y0 + 1)
    z = np.ascontiguousarray(p[:, 2])
    lowest = _lowest_per_cell(cx - x0, cy - y0, z, valid, shape[0], shape[1])
    gx, gy = np.meshgrid(np.arange(shape[0]) + x0, np.arange(shape[1]) + y0, indexing="ij")
    distance = np.hypot((gx + 0.5) * fit.cell_m, (gy + 0.5) * fit.cell_m)
    occupied = np.isfinite(lowest)
    near = occupied & (distance >= NEAR_RANGE_M[0]) & (distance <= NEAR_RANGE_M[1])
    h0 = float(np.median(lowest[near])) if near.any() else float(lowest[occupied].min())
    candidate = occupied & (lowest <= h0 + fit.height_tol_m + distance * fit.max_slope)
    return _near_candidate_floor(cx - x0, cy - y0, z, valid, lowest, candidate, fit.height_tol_m)


@njit(cache=True)
def _lowest_per_cell(cx, cy, z, valid, nx, ny):  # type: ignore[no-untyped-def]
    """(nx, ny) the lowest z of each cell's valid points, +inf where a cell has none."""
    lowest = np.full((nx, ny), np.inf)
    for i in range(z.size):
        if valid[i] and z[i] < lowest[cx[i], cy[i]]:
            lowest[cx[i], cy[i]] = z[i]
    return lowest


@njit(cache=True)
def _near_candidate_floor(cx, cy, z, valid, lowest, candidate, tol):  # type: ignore[no-untyped-def]
    """(N,) whether a valid point lies within `tol` above the lowest point of a candidate
    cell among its own and the eight around it."""
    nx, ny = lowest.shape
    out = np.zeros(z.size, dtype=np.bool_)
    for i in range(z.size):
        if not valid[i]:
            continue
        for a in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for b in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                if candidate[a, b] and z[i] - lowest[a, b] <= tol:
                    out[i] = True
    return out
