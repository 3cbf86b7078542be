"""Is a frame a scan of a given sensor? Refuse only what is clearly another sensor.

Real scans carry returns that no nominal sensor description allows for: nuScenes keyframes
hold the ego vehicle's body and near-field returns (a quarter of the points within 3 m, some
at apparent elevations down to -59 deg), zero-range placeholders, and a few multipath
returns far below the ground. A check that counts every point refuses such frames although
they are exactly what the sensor records. So the judgement rests on what the sensor's beam
geometry does decide:

- with a ring column (nuScenes .pcd.bin, RADIATE): every ring id must be a channel of the
  profile, and each well-populated ring's median elevation (returns beyond the near field)
  must lie within one beam spacing of the profile's elevation for that channel;
- without one: of the returns beyond the near field, at most `MAX_OUTSIDE_FOV` may lie
  outside the profile's vertical field of view widened by `FOV_MARGIN_DEG`.

Returns nearer than `NEAR_FIELD_M` are not judged: there the lasers' own offsets from the
sensor origin (centimetres) and the vehicle's body make apparent elevations meaningless.
Frames with fewer than `MIN_JUDGED_POINTS` returns beyond it (a tiny sample) pass.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from lads.errors import InvalidPointsError
from lads.sensors.profile import SensorProfile

# Apparent-elevation error of a laser mounted ~0.1 m off the sensor origin exceeds the FOV
# margin below ~3 m; nuScenes' ego-body returns also lie within 2.3 m.
NEAR_FIELD_M = 3.0
FOV_MARGIN_DEG = 2.0
MAX_OUTSIDE_FOV = 0.05
MIN_JUDGED_POINTS = 200
MAX_SAMPLED_POINTS = 32768
# A ring is judged when it holds at least this many returns beyond the near field; the frame
# is refused when more than MAX_MISPLACED_RINGS of the judged rings sit off their channel.
MIN_RING_POINTS = 20
MAX_MISPLACED_RINGS = 0.25


def elevation_deg(xyz: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(N,) apparent elevation atan2(z, hypot(x, y)) in degrees of (N, 3) points in m."""
    p = np.asarray(xyz, dtype=np.float64)
    return np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))


def check_scan_of(
    xyz: npt.ArrayLike,
    profile: SensorProfile,
    *,
    ring: npt.ArrayLike | None = None,
    where: str = "frame",
) -> None:
    """Raise InvalidPointsError if the (N, 3) points (m) are clearly not a scan of `profile`.

    Args:
        xyz: (N, 3) point coordinates in m, sensor frame.
        profile: the sensor the frame is said to come from.
        ring: optional (N,) ring (channel) ids, 0 = lowest beam.
        where: the frame's name for the message.
    """
    # An even stride over at most MAX_SAMPLED_POINTS returns: the shares and per-ring
    # medians judged here are as clear on a sample as on the whole frame, at a quarter of
    # the cost of a 64-beam scan.
    points = np.asarray(xyz)
    step = max(1, -(-len(points) // MAX_SAMPLED_POINTS))
    if ring is not None:
        p = points[::step].astype(np.float64)
        far = np.linalg.norm(p, axis=1) > NEAR_FIELD_M
        if int(far.sum()) >= MIN_JUDGED_POINTS:
            rings = np.asarray(ring, dtype=np.float64)[::step]
            _check_rings(rings, far, elevation_deg(p[far]), profile, where)
        return
    low, high = profile.vertical_fov_deg
    if points.ndim != 2 or points.shape[1] != 3 or not np.issubdtype(points.dtype, np.number):
        return  # not points at all: the caller's own checks name what is wrong
    judged, outside = _fov_counts(
        points, step, NEAR_FIELD_M, _tan_deg(low - FOV_MARGIN_DEG), _tan_deg(high + FOV_MARGIN_DEG)
    )
    if judged < MIN_JUDGED_POINTS:
        return
    share = outside / judged
    if share > MAX_OUTSIDE_FOV:
        raise InvalidPointsError(
            f"{where}: {share:.0%} of the {judged} returns beyond {NEAR_FIELD_M:g} m lie "
            f"outside the vertical field of view {low:g}..{high:g} deg (+-{FOV_MARGIN_DEG:g}) of "
            f"sensor profile '{profile.name}' (nearer returns, such as the vehicle's body, are "
            "not counted); the frame is not a scan of that sensor. Read it with the reader of "
            "its own dataset, or pass a sensor profile of its LiDAR (lads profiles)."
        )


def _tan_deg(angle_deg: float) -> float:
    """tan of an elevation in degrees, +-inf at or beyond +-90."""
    if abs(angle_deg) >= 90.0:
        return math.copysign(math.inf, angle_deg)
    return math.tan(math.radians(angle_deg))


@numba.njit(cache=True, nogil=True)
def _fov_counts(
    points: npt.NDArray[Any], step: int, near_m: float, tan_low: float, tan_high: float
) -> tuple[int, int]:
    """(judged, outside) of every step-th (N, 3) point: those farther than near_m, and of
    them those below the elevation of tan_low or above that of tan_high (z against rho tan,
    no arctangent: one pass, no copies)."""
    judged = outside = 0
    near2 = near_m * near_m
    for i in range(0, points.shape[0], step):
        x, y, z = float(points[i, 0]), float(points[i, 1]), float(points[i, 2])
        rho2 = x * x + y * y
        if not rho2 + z * z > near2:  # near, or NaN: not judged
            continue
        judged += 1
        rho = math.sqrt(rho2)
        if z < rho * tan_low or z > rho * tan_high:
            outside += 1
    return judged, outside


def _check_rings(
    ring: npt.NDArray[np.float64],
    far: npt.NDArray[np.bool_],
    elevation: npt.NDArray[np.float64],
    profile: SensorProfile,
    where: str,
) -> None:
    ids = ring.astype(np.int64)
    bad = (ids != ring) | (ids < 0) | (ids >= profile.channels)
    if bad.any():
        values = np.unique(ring[bad])[:5]
        raise InvalidPointsError(
            f"{where}: the ring column holds {int(bad.sum())} values that are not channels "
            f"0..{profile.channels - 1} of sensor profile '{profile.name}' (e.g. "
            f"{', '.join(f'{v:g}' for v in values)}); the frame is not a scan of that sensor."
        )
    table = np.asarray(profile.elevation_deg)
    spacing = np.gradient(table) if table.size > 1 else np.ones(1)
    far_ids = ids[far]
    judged, misplaced = 0, []
    for channel in np.unique(far_ids):
        values = elevation[far_ids == channel]
        if values.size < MIN_RING_POINTS:
            continue
        judged += 1
        error = float(np.median(values) - table[channel])
        if abs(error) > abs(spacing[channel]):
            misplaced.append((int(channel), error))
    if judged and len(misplaced) > MAX_MISPLACED_RINGS * judged:
        shown = ", ".join(f"ring {c} off by {e:+.1f} deg" for c, e in misplaced[:4])
        raise InvalidPointsError(
            f"{where}: {len(misplaced)} of {judged} rings have a median elevation more than one "
            f"beam spacing from sensor profile '{profile.name}' ({shown}); the frame is not a "
            "scan of that sensor. Pass a sensor profile of its LiDAR (lads profiles)."
        )
