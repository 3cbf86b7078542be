"""Organise a point cloud into a range image: rows = laser channel, columns = azimuth.

Pure numpy, no file I/O (docs/physics.md §10.3, with one change): the row is the point's
*channel* (ring column, or nearest elevation in the sensor profile), top row = highest
channel, so no point is lost outside a nominal vertical FOV. Columns follow the azimuth,
u = 0.5 (-atan2(y, x) / pi + 1) W. Among points sharing a pixel the nearest owns it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError, InvalidPointsError
from lads.frame import not_lasers
from lads.physics.image_kernels import organised_pixels, point_ranges
from lads.sensors.profile import SensorProfile

MIN_RANGE_M = 1e-6  # docs/physics.md §10.3: a point is valid if its range exceeds this

FloatArray = npt.NDArray[np.float32]


@dataclass(frozen=True, slots=True)
class RangeImage:
    """A point cloud organised by channel (rows) and azimuth (columns).

    Attributes:
        index: (H, W) int64 index of the point that owns each pixel (the nearest one), -1
            where empty. Row 0 is the highest channel (H - 1 - channel).
        range_m: (H, W) float32 range of the owner in m, 0 where empty.
        xyz: (H, W, 3) float32 coordinates of the owner in m, 0 where empty.
        row: (N,) int64 row of every input point (owner or not).
        col: (N,) int64 column of every input point.
    """

    index: npt.NDArray[np.int64]
    range_m: FloatArray
    xyz: FloatArray
    row: npt.NDArray[np.int64]
    col: npt.NDArray[np.int64]

    @property
    def mask(self) -> npt.NDArray[np.bool_]:
        """(H, W) bool, True where a point owns the pixel."""
        return self.index >= 0


def range_m(xyz: npt.ArrayLike) -> FloatArray:
    """Euclidean range of each point from the sensor origin.

    Args:
        xyz: (N, 3) coordinates in m, any real dtype.

    Returns:
        (N,) float32 range in m (zero-range points are allowed here and give 0).

    Raises:
        InvalidPointsError: wrong shape, or NaN/inf coordinates.
    """
    return checked_xyz(xyz, allow_zero=True)[1].astype(np.float32)


def channels(
    xyz: npt.ArrayLike, profile: SensorProfile, ring: npt.ArrayLike | None = None
) -> npt.NDArray[np.int64]:
    """Laser channel of each point: the ring column when given, else the nearest elevation.

    Args:
        xyz: (N, 3) coordinates in m.
        profile: sensor profile; `profile.channels` bounds the ring, its elevation table
            assigns channels when `ring` is None.
        ring: optional (N,) ring ids, 0 = lowest beam; integer dtype or integral floats
            (nuScenes stores the ring as float32).

    Returns:
        (N,) int64 channel in [0, profile.channels).

    Raises:
        InvalidPointsError: bad xyz (shape, NaN/inf, zero range), or a ring of the wrong
            shape, non-integral, or outside [0, profile.channels).
    """
    xyz64, _ = checked_xyz(xyz)
    return channels_of(xyz64, profile, ring)


def project(
    xyz: npt.ArrayLike,
    profile: SensorProfile,
    *,
    channel: npt.ArrayLike | None = None,
    width: int | None = None,
) -> RangeImage:
    """Organise points into a (profile.channels, W) range image; the nearest point wins.

    Args:
        xyz: (N, 3) coordinates in m.
        profile: sensor profile (rows = its channels, default width its range_image_width).
        channel: optional (N,) channel per point (e.g. from `channels`); default nearest
            elevation.
        width: azimuth bins W (>= 3); default `profile.range_image_width`.

    Returns:
        RangeImage. Among points sharing a pixel the nearest owns it, ties going to the
        lower input index (one compiled pass, `image_kernels.pixel_owners`; no reliance on
        the unspecified order of repeated fancy-index assignment).

    Raises:
        InvalidPointsError: bad xyz or channel. ConfigError: width < 3.
    """
    xyz64, r = checked_xyz(xyz)
    chan = channels_of(xyz64, profile, channel)
    return organise(xyz64, r, chan, profile.channels, image_width(profile, width))


def checked_xyz(
    xyz: npt.ArrayLike, *, allow_zero: bool = False
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(N, 3) float64 coordinates and (N,) float64 ranges in m, validated.

    Raises:
        InvalidPointsError: wrong shape or dtype, NaN/inf, or (unless allow_zero) zero range.
    """
    arr = np.asarray(xyz)
    if arr.ndim != 2 or arr.shape[1] != 3 or not np.issubdtype(arr.dtype, np.number):
        raise InvalidPointsError(
            f"xyz: expected an (N, 3) real array in m, got shape {arr.shape} and dtype "
            f"{arr.dtype}; pass points[:, :3]."
        )
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    r, bad = point_ranges(arr)
    if bad:
        raise InvalidPointsError(
            f"xyz: {bad} of {len(arr)} points have NaN or infinite coordinates."
        )
    zero = 0 if allow_zero else int(np.count_nonzero(r <= MIN_RANGE_M))
    if zero:
        raise InvalidPointsError(
            f"xyz: {zero} of {len(arr)} points lie at zero range (<= {MIN_RANGE_M:g} m), "
            "where no direction is defined; they are not LiDAR returns."
        )
    return arr, r


def channels_of(
    xyz64: npt.NDArray[np.float64], profile: SensorProfile, ring: npt.ArrayLike | None
) -> npt.NDArray[np.int64]:
    """`channels` on already validated coordinates."""
    if ring is None:
        return profile.channel_of(xyz64)
    arr = np.asarray(ring)
    if arr.shape != (len(xyz64),) or not np.issubdtype(arr.dtype, np.number):
        raise InvalidPointsError(
            f"ring: shape {arr.shape} and dtype {arr.dtype}, expected ({len(xyz64)},) numbers."
        )
    bad = not_lasers(arr, profile.channels)
    as_int = np.where(bad, -1, arr).astype(np.int64)
    count = int(np.count_nonzero(bad))
    if count:
        raise InvalidPointsError(
            f"ring: {count} values are not integers in [0, {profile.channels}) for profile "
            f"'{profile.name}' (e.g. {arr[bad][:3].tolist()}); check the profile."
        )
    return as_int


def image_width(profile: SensorProfile, width: int | None) -> int:
    w = profile.range_image_width if width is None else width
    if isinstance(w, bool) or not isinstance(w, int | np.integer) or w < 3:
        raise ConfigError(f"width = {width!r}; expected an integer >= 3 azimuth bins.")
    return int(w)


def organise(
    xyz64: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
    chan: npt.NDArray[np.int64],
    height: int,
    width: int,
) -> RangeImage:
    """`project` on validated coordinates, ranges and channels (rows = height - 1 - chan)."""
    # numpy's vectorised arctangent; the rest in one compiled pass with the same arithmetic.
    row, col, index, range_img, xyz_img = organised_pixels(
        np.arctan2(xyz64[:, 1], xyz64[:, 0]),
        np.ascontiguousarray(chan, dtype=np.int64),
        np.ascontiguousarray(r, dtype=np.float64),
        np.ascontiguousarray(xyz64, dtype=np.float64),
        height,
        width,
    )
    return RangeImage(
        index.reshape(height, width),
        range_img.reshape(height, width),
        xyz_img.reshape(height, width, 3),
        row,
        col,
    )
