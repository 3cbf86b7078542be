"""How close a transferred scan is to the target sensor's own scan of the scene
(docs/transfer.md §5).

Both scans are binned on the target's beam grid (ring, azimuth column). Per-ring counts are
compared on the rings the source's field of view covers (the others cannot be made from the
source: they are listed apart). Range, label and intensity errors are read on the beams both
scans returned; Chamfer distance on the points of covered rings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from lads.physics.materials import MAX_CLASS_ID


@dataclass(frozen=True, slots=True)
class GridScan:
    """A scan on the target's beam grid: points, ring, column, labels, intensity."""

    xyz: npt.NDArray[np.floating]
    ring: npt.NDArray[np.int64]
    column: npt.NDArray[np.int64]
    labels: npt.NDArray[np.integer]
    intensity: npt.NDArray[np.floating]


def grid_column(xyz: npt.ArrayLike, width: int, offset_rad: float) -> npt.NDArray[np.int64]:
    """(N,) azimuth column of each point on a grid of `width` columns starting at
    `offset_rad` (column j spans offset + [j, j + 1) 2 pi / width)."""
    pts = np.asarray(xyz, dtype=np.float64)
    az = np.mod(np.arctan2(pts[:, 1], pts[:, 0]) - offset_rad, 2.0 * math.pi)
    return np.minimum((az / (2.0 * math.pi / width)).astype(np.int64), width - 1)


def compare_scans(
    method: GridScan, reference: GridScan, channels: int, width: int, covered: npt.ArrayLike
) -> dict[str, Any]:
    """Metrics of `method` against `reference` on a (channels, width) grid.

    Args:
        covered: (channels,) bool, rings the source's field of view covers.

    Returns:
        ring_count_error_mean / _max: |n - n_ref| / n_ref over covered rings with returns;
        range_error_median_m / _p90_m, label_accuracy, intensity_mae (target units), on
        beams both returned; pixel_recall: share of the reference's covered beams the method
        returned; chamfer_m: mean of the two mean nearest-neighbour distances (covered
        rings); points, points_reference.
    """
    cov = np.asarray(covered, dtype=bool)
    n_m = np.bincount(method.ring, minlength=channels)
    n_r = np.bincount(reference.ring, minlength=channels)
    rings = np.flatnonzero(cov & (n_r > 0))
    count_err = np.abs(n_m[rings] - n_r[rings]) / n_r[rings]
    img_m, img_r = _image(method, channels, width), _image(reference, channels, width)
    both = (img_m >= 0) & (img_r >= 0)
    i_m, i_r = img_m[both], img_r[both]
    r_m = np.linalg.norm(np.asarray(method.xyz, np.float64)[i_m], axis=1)
    r_r = np.linalg.norm(np.asarray(reference.xyz, np.float64)[i_r], axis=1)
    err = np.abs(r_m - r_r)
    cls_m = np.asarray(method.labels).astype(np.int64)[i_m] & MAX_CLASS_ID
    cls_r = np.asarray(reference.labels).astype(np.int64)[i_r] & MAX_CLASS_ID
    ref_cov = (img_r >= 0) & cov[:, None]
    in_m = cov[method.ring]
    in_r = cov[reference.ring]
    return {
        "ring_count_error_mean": float(count_err.mean()) if rings.size else None,
        "ring_count_error_max": float(count_err.max()) if rings.size else None,
        "range_error_median_m": float(np.median(err)) if err.size else None,
        "range_error_p90_m": float(np.quantile(err, 0.9)) if err.size else None,
        "label_accuracy": float((cls_m == cls_r).mean()) if err.size else None,
        "intensity_mae": float(
            np.abs(
                np.asarray(method.intensity, np.float64)[i_m]
                - np.asarray(reference.intensity, np.float64)[i_r]
            ).mean()
        )
        if err.size
        else None,
        "pixel_recall": float((both & ref_cov).sum() / max(ref_cov.sum(), 1)),
        "chamfer_m": _chamfer(np.asarray(method.xyz)[in_m], np.asarray(reference.xyz)[in_r]),
        "points": int(len(method.ring)),
        "points_reference": int(len(reference.ring)),
    }


def _image(scan: GridScan, channels: int, width: int) -> npt.NDArray[np.int64]:
    """(channels, width) index of the nearest point on each beam, -1 where none."""
    img = np.full((channels, width), -1, dtype=np.int64)
    rng = np.linalg.norm(np.asarray(scan.xyz, np.float64), axis=1)
    order = np.argsort(-rng, kind="stable")  # farthest first: the nearest is written last
    img[scan.ring[order], scan.column[order]] = order
    return img


def _chamfer(a: npt.ArrayLike, b: npt.ArrayLike) -> float | None:
    pa, pb = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if len(pa) == 0 or len(pb) == 0:
        return None
    d_ab = cKDTree(pb).query(pa)[0]
    d_ba = cKDTree(pa).query(pb)[0]
    return float(0.5 * (d_ab.mean() + d_ba.mean()))
