"""What users do today to fake another sensor, for comparison (docs/transfer.md §5).

- Ring dropping (Robo3D "cross-sensor", MultiCorrupt "beams reducing", LiDAR Distillation's
  pseudo low-beam data): keep the source rings nearest the target's elevations. It can only
  ever keep a subset of the source's rays: the elevations stay the source's, nothing new is
  occluded, and a denser target gets no new rings.
- Row resampling of the range image: each target beam (ring, azimuth column) takes the source
  return of the nearest row and column, so the target's azimuth resolution is met too; rows
  repeat where the target is denser.

Both keep the source's points as they are (coordinates, labels) and re-encode intensity into
the target's encoding through reflectivity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.physics.projection import MIN_RANGE_M
from lads.sensors.profile import SensorProfile
from lads.transfer.metrics import grid_column


@dataclass(frozen=True, slots=True)
class BaselineScan:
    """A baseline's output: points, target ring and azimuth column, labels, intensity.

    Attributes:
        xyz: (M, 3) float32, m. intensity: (M,) float32 in the target's encoding.
        labels: (M,) uint32. ring: (M,) int64 target channel. column: (M,) int64.
    """

    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    labels: npt.NDArray[np.uint32]
    ring: npt.NDArray[np.int64]
    column: npt.NDArray[np.int64]


def nearest_rings(
    source_el_deg: npt.ArrayLike, target_el_deg: npt.ArrayLike
) -> npt.NDArray[np.int64]:
    """(target channels,) the source channel nearest each target elevation (degrees,
    ascending), -1 where none lies within half the target's local ring gap (outside the
    source's field of view)."""
    src = np.asarray(source_el_deg, dtype=np.float64)
    tgt = np.asarray(target_el_deg, dtype=np.float64)
    gaps = np.diff(tgt)
    half = 0.5 * np.maximum(np.concatenate([[gaps[0]], gaps]), np.concatenate([gaps, [gaps[-1]]]))
    nearest = np.abs(src[None, :] - tgt[:, None]).argmin(axis=1)
    return np.where(np.abs(src[nearest] - tgt) <= half, nearest, -1)


def ring_drop(
    xyz: npt.NDArray[np.floating],
    intensity: npt.NDArray[np.floating],
    labels: npt.NDArray[np.integer],
    ring: npt.NDArray[np.integer],
    source: SensorProfile,
    target: SensorProfile,
    *,
    azimuth_offset_rad: float = 0.0,
) -> BaselineScan:
    """The source points of the rings nearest the target's (each source ring at most once:
    the target ring nearest to it wins), every k-th point of each ring when the source's
    azimuth resolution is k times the target's."""
    chosen = nearest_rings(source.elevation_deg, target.elevation_deg)
    tgt_el = np.asarray(target.elevation_deg)
    src_el = np.asarray(source.elevation_deg)
    to_target = np.full(source.channels, -1, dtype=np.int64)
    for k in np.argsort(np.abs(src_el[np.maximum(chosen, 0)] - tgt_el))[::-1]:
        if chosen[k] >= 0:
            to_target[chosen[k]] = k  # nearest target ring assigned last, so it wins
    keep = np.flatnonzero(to_target[np.asarray(ring, dtype=np.int64)] >= 0)
    # Every k-th point of a ring, k the ratio of azimuth resolutions ("and every second
    # point" of the beam-reducing corruptions), so a ring holds the target's point count.
    k = max(1, round(source.range_image_width / target.range_image_width))
    if k > 1:
        az = np.arctan2(np.asarray(xyz)[keep, 1], np.asarray(xyz)[keep, 0])
        order = keep[np.lexsort((az, np.asarray(ring)[keep]))]
        rings_sorted = np.asarray(ring)[order]
        starts = np.r_[0, np.flatnonzero(np.diff(rings_sorted)) + 1]
        rank = np.arange(len(order)) - np.repeat(starts, np.diff(np.r_[starts, len(order)]))
        keep = np.sort(order[rank % k == 0])
    return _baseline(
        xyz,
        intensity,
        labels,
        to_target[np.asarray(ring)[keep]],
        keep,
        source,
        target,
        azimuth_offset_rad,
    )


def row_resample(
    xyz: npt.NDArray[np.floating],
    intensity: npt.NDArray[np.floating],
    labels: npt.NDArray[np.integer],
    ring: npt.NDArray[np.integer],
    source: SensorProfile,
    target: SensorProfile,
    *,
    azimuth_offset_rad: float = 0.0,
) -> BaselineScan:
    """Per target beam, the nearest source return of the nearest source ring within one
    target azimuth step."""
    chosen = nearest_rings(source.elevation_deg, target.elevation_deg)
    pts = np.asarray(xyz, dtype=np.float64)
    ok = np.linalg.norm(pts, axis=1) > MIN_RANGE_M
    width = target.range_image_width
    col = grid_column(pts, width, azimuth_offset_rad)
    ring64 = np.asarray(ring, dtype=np.int64)
    rng_m = np.linalg.norm(pts, axis=1)
    picked_rows, picked_ring = [], []
    for k, s in enumerate(chosen):
        if s < 0:
            continue
        mine = np.flatnonzero(ok & (ring64 == s))
        order = mine[np.lexsort((rng_m[mine], col[mine]))]  # per column, nearest first
        first = np.unique(col[order], return_index=True)[1]
        picked_rows.append(order[first])
        picked_ring.append(np.full(first.size, k, dtype=np.int64))
    rows = np.concatenate(picked_rows) if picked_rows else np.zeros(0, np.int64)
    rings = np.concatenate(picked_ring) if picked_ring else np.zeros(0, np.int64)
    return _baseline(xyz, intensity, labels, rings, rows, source, target, azimuth_offset_rad)


def _baseline(
    xyz: npt.NDArray[np.floating],
    intensity: npt.NDArray[np.floating],
    labels: npt.NDArray[np.integer],
    rings: npt.NDArray[np.int64],
    rows: npt.NDArray[np.int64],
    source: SensorProfile,
    target: SensorProfile,
    offset: float,
) -> BaselineScan:
    pts = np.asarray(xyz, dtype=np.float64)[rows]
    refl = source.intensity.to_reflectivity(np.asarray(intensity)[rows])
    return BaselineScan(
        xyz=pts.astype(np.float32),
        intensity=target.intensity.from_reflectivity(refl),
        labels=np.asarray(labels)[rows].astype(np.uint32),
        ring=rings.astype(np.int64),
        column=grid_column(pts, target.range_image_width, offset),
    )
