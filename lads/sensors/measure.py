"""Measure per-channel beam elevations on real scans, for the sensor profile YAMLs.

Three ways, for three kinds of files:
* a ring column (nuScenes, RADIATE): `elevations_from_rings`;
* no ring column, but points stored ring by ring in rotation order (SemanticKITTI .bin):
  `rings_from_scan_order` recovers the ring of every point from the azimuth wrap-arounds,
  then `elevations_from_rings`;
* neither (WADS .bin, stored column by column with dropped returns): the per-beam
  elevations are sharp peaks of the elevation histogram, `elevations_from_histogram`.

Elevations are *apparent* elevations seen from the sensor origin, atan2(z, hypot(x, y)),
because that is what every consumer of the table (`SensorProfile.channel_of`, range-image
rows, the vertical field of view) computes from xyz. Lasers mounted off the origin (the
HDL-64E's upper block sits ~0.21 m above it) look higher than their nominal angle at short
range, so only points beyond `min_range_m` are used and the median is taken.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.signal import find_peaks

from lads.errors import InputDataError, InvalidPointsError

DEFAULT_MIN_RANGE_M = 5.0
# Rings whose returns all lie near the sensor (the lowest KITTI and nuScenes beams hit the
# ground at 3-4 m) still need a value: their range cut is halved until this many remain.
MIN_POINTS_BEYOND = 100
# Below this the cut stops halving: nuScenes returns within ~2 m are the ego vehicle's body.
FLOOR_RANGE_M = 2.0


def elevation_deg(xyz: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.float64]:
    """Apparent elevation of each point seen from the origin.

    Args:
        xyz: (N, 3) coordinates in m (any float dtype).

    Returns:
        (N,) float64 elevation in degrees, atan2(z, hypot(x, y)).
    """
    xyz = _checked_xyz(xyz)
    return np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))


def rings_from_scan_order(
    xyz: npt.NDArray[np.floating[Any]], channels: int
) -> npt.NDArray[np.int64]:
    """Ring (channel, 0 = lowest beam) of every point of a file stored ring by ring.

    KITTI-style .bin files hold one ring after the other, each one full rotation in
    azimuth order. A new ring starts where the azimuth, taken in [0, 2 pi), drops by more
    than pi. The ring whose median elevation is higher is taken as the top one, so files
    stored top-down (KITTI) and bottom-up both work.

    Args:
        xyz: (N, 3) coordinates in m, in file order.
        channels: number of beams the file must contain.

    Returns:
        (N,) int64 channel per point, 0 = lowest beam.

    Raises:
        InputDataError: the wrap-arounds do not split the file into `channels` rings (the
            file is not stored ring by ring, or points were reordered or filtered).
    """
    xyz = _checked_xyz(xyz)
    yaw = np.mod(np.arctan2(xyz[:, 1], xyz[:, 0]), 2.0 * np.pi)
    starts = np.flatnonzero(np.diff(yaw) < -np.pi) + 1
    if len(starts) != channels - 1:
        raise InputDataError(
            f"scan order: azimuth wrap-arounds split the {len(xyz)} points into "
            f"{len(starts) + 1} rings, expected {channels}. The file is not stored ring by "
            "ring; measure with elevations_from_histogram instead."
        )
    order = np.zeros(len(xyz), dtype=np.int64)
    order[starts] = 1
    order = np.cumsum(order)
    elev = elevation_deg(xyz)
    top_down = np.median(elev[order == 0]) > np.median(elev[order == channels - 1])
    return (channels - 1 - order) if top_down else order


def elevations_from_rings(
    xyz: npt.NDArray[np.floating[Any]],
    ring: npt.ArrayLike,
    channels: int,
    *,
    min_range_m: float = DEFAULT_MIN_RANGE_M,
) -> npt.NDArray[np.float64]:
    """Median apparent elevation of each ring, from points beyond `min_range_m`.

    A ring with fewer than 100 points beyond `min_range_m` halves the cut (5 -> 2.5 m) as
    long as it stays above 2 m, for beams that only ever hit nearby ground; if that still
    leaves fewer than 100 points, the farther half of the ring's points is used.

    Args:
        xyz: (N, 3) coordinates in m.
        ring: (N,) integer ring per point, 0 = lowest beam.
        channels: number of beams.
        min_range_m: range below which points are ignored, m.

    Returns:
        (channels,) float64 elevations in degrees, strictly increasing.

    Raises:
        InputDataError: a ring id outside [0, channels), a ring without points, or
            elevations that do not increase with the ring id.
    """
    xyz = _checked_xyz(xyz)
    ring = np.asarray(ring)
    if ring.shape != (len(xyz),) or (ring.size and (ring.min() < 0 or ring.max() >= channels)):
        raise InputDataError(
            f"ring: expected ({len(xyz)},) integers in [0, {channels}), got shape "
            f"{ring.shape}; pass the ring column that belongs to these points."
        )
    ring = ring.astype(np.int64)
    elev = elevation_deg(xyz)
    range_m = np.linalg.norm(xyz, axis=1)
    table = np.empty(channels)
    for channel in range(channels):
        in_ring = ring == channel
        if not in_ring.any():
            raise InputDataError(f"ring {channel} has no points; cannot measure its elevation.")
        cut_m = min_range_m
        use = in_ring & (range_m > cut_m)
        while use.sum() < MIN_POINTS_BEYOND and cut_m / 2 >= FLOOR_RANGE_M:
            cut_m /= 2
            use = in_ring & (range_m > cut_m)
        if use.sum() < MIN_POINTS_BEYOND:
            use = in_ring & (range_m >= np.median(range_m[in_ring]))
        table[channel] = np.median(elev[use])
    _require_increasing(table, "rings")
    return table


def elevations_from_scan_order(
    xyz: npt.NDArray[np.floating[Any]],
    channels: int,
    *,
    min_range_m: float = DEFAULT_MIN_RANGE_M,
) -> npt.NDArray[np.float64]:
    """Per-channel elevations of a file stored ring by ring (KITTI .bin).

    `rings_from_scan_order` then `elevations_from_rings`; same shapes, units and errors.
    """
    ring = rings_from_scan_order(xyz, channels)
    return elevations_from_rings(xyz, ring, channels, min_range_m=min_range_m)


def elevations_from_histogram(
    xyz: npt.NDArray[np.floating[Any]],
    channels: int,
    *,
    min_range_m: float = DEFAULT_MIN_RANGE_M,
    bin_deg: float = 0.01,
    min_spacing_deg: float = 0.1,
) -> npt.NDArray[np.float64]:
    """Per-channel elevations as the peaks of the elevation histogram (WADS .bin).

    For sensors whose points sit at (nearly) exact beam elevations: the `channels` highest
    peaks of a `bin_deg` histogram over points beyond `min_range_m`, at least
    `min_spacing_deg` apart, each refined to the median elevation of the points nearer to
    it than to any other peak.

    Args:
        xyz: (N, 3) coordinates in m.
        channels: number of beams.
        min_range_m: range below which points are ignored, m.
        bin_deg: histogram bin width, degrees.
        min_spacing_deg: smallest beam spacing the sensor may have, degrees.

    Returns:
        (channels,) float64 elevations in degrees, strictly increasing.

    Raises:
        InputDataError: fewer than `channels` peaks (no clear beam structure).
    """
    elev = elevation_deg(xyz)[np.linalg.norm(_checked_xyz(xyz), axis=1) > min_range_m]
    if elev.size == 0:
        raise InputDataError(f"no points beyond {min_range_m} m; cannot measure elevations.")
    edges = np.arange(elev.min() - bin_deg, elev.max() + 2 * bin_deg, bin_deg)
    counts, edges = np.histogram(elev, bins=edges)
    peaks, _ = find_peaks(counts, distance=max(1, int(round(min_spacing_deg / bin_deg))))
    if len(peaks) < channels:
        raise InputDataError(
            f"elevation histogram: {len(peaks)} peaks, expected {channels}; the scan has no "
            "clear per-beam structure (use a ring column or scan order instead)."
        )
    strongest = np.sort(peaks[np.argsort(counts[peaks])[::-1][:channels]])
    centres = 0.5 * (edges[strongest] + edges[strongest + 1])
    nearest = np.searchsorted(0.5 * (centres[1:] + centres[:-1]), elev)
    table = np.array([np.median(elev[nearest == c]) for c in range(channels)])
    _require_increasing(table, "histogram peaks")
    return table


def vertical_fov_deg(elevation: npt.ArrayLike) -> tuple[float, float]:
    """Field of view spanning the elevations plus half the local channel spacing each side.

    Args:
        elevation: (C,) strictly increasing elevations in degrees, C >= 2.

    Returns:
        (lowest, highest) in degrees, rounded outwards to 0.001 degree.
    """
    table = np.asarray(elevation, dtype=np.float64)
    low = table[0] - 0.5 * (table[1] - table[0])
    high = table[-1] + 0.5 * (table[-1] - table[-2])
    return float(np.floor(low * 1000) / 1000), float(np.ceil(high * 1000) / 1000)


def _require_increasing(table: npt.NDArray[np.float64], method: str) -> None:
    if np.any(np.diff(table) <= 0):
        raise InputDataError(
            f"elevations measured from {method} are not strictly increasing with the "
            f"channel id ({np.round(table, 3).tolist()}); check the channel order of the data."
        )


def _checked_xyz(xyz: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.float64]:
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] < 3:
        raise InvalidPointsError(f"xyz: expected an (N, 3) array in m, got shape {xyz.shape}.")
    xyz = xyz[:, :3]
    if not np.isfinite(xyz).all():
        raise InvalidPointsError("xyz: contains NaN or inf; remove or fix those rows first.")
    return xyz
