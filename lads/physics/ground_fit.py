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

# Cells whose lowest point sets the reference ground height: near the sensor, where a street
# scan always sees road (m, horizontal distance).
NEAR_RANGE_M = (3.0, 15.0)


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
        xyz: (N, 3) points in the sensor frame, m, z up. Zero-range rows are never ground.
        fit: the settings.
    """
    p = np.asarray(xyz, dtype=np.float64)
    n = p.shape[0]
    valid = np.isfinite(p).all(axis=1) & (np.einsum("ij,ij->i", p, p) > 0)
    if not valid.any():
        return np.zeros(n, dtype=bool)
    cx = np.floor(p[:, 0] / fit.cell_m).astype(np.int64)
    cy = np.floor(p[:, 1] / fit.cell_m).astype(np.int64)
    cells, cell_of = _cells(cx, cy, valid)
    lowest = np.full(len(cells), np.inf)
    np.minimum.at(lowest, cell_of[valid], p[valid, 2])
    centre = (cells + 0.5) * fit.cell_m
    distance = np.hypot(centre[:, 0], centre[:, 1])
    near = (distance >= NEAR_RANGE_M[0]) & (distance <= NEAR_RANGE_M[1])
    h0 = float(np.median(lowest[near])) if near.any() else float(np.min(lowest))
    candidate = lowest <= h0 + fit.height_tol_m + distance * fit.max_slope
    ground = np.zeros(n, dtype=bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            neighbour = _lookup(cells, cx + dx, cy + dy)
            ok = valid & (neighbour >= 0)
            k = neighbour[ok]
            near_floor = p[ok, 2] - lowest[k] <= fit.height_tol_m
            ground[np.flatnonzero(ok)[candidate[k] & near_floor]] = True
    return ground


def _cells(
    cx: npt.NDArray[np.int64], cy: npt.NDArray[np.int64], valid: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """(C, 2) the occupied cells, sorted, and (N,) each point's cell index (-1 if invalid)."""
    cells, inverse = np.unique(np.column_stack([cx[valid], cy[valid]]), axis=0, return_inverse=True)
    cell_of = np.full(cx.size, -1, dtype=np.int64)
    cell_of[valid] = inverse.ravel()
    return cells, cell_of


def _lookup(
    cells: npt.NDArray[np.int64], cx: npt.NDArray[np.int64], cy: npt.NDArray[np.int64]
) -> npt.NDArray[np.int64]:
    """(N,) index of the cell (cx, cy) in `cells`, -1 where it is not occupied."""
    keys = cells[:, 0] * (1 << 32) + cells[:, 1]
    wanted = cx * (1 << 32) + cy
    pos = np.clip(np.searchsorted(keys, wanted), 0, len(keys) - 1)
    return np.where(keys[pos] == wanted, pos, -1)
