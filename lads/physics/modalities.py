"""Per-point modalities for intensity models: range, channel, incidence, reflectance, I_phy.

Pure numpy (plus compiled loops and, for some scans, a k-d tree), no file I/O. Every
function returns one value per input point: points are never dropped, because labels and
output files are matched by index (docs/physics.md §10.7 item 4).

The range image (rows = channel, columns = azimuth) lives in `lads.physics.projection`;
range_m, channels, project and RangeImage are re-exported here.

Incidence: cos(theta) = |n . r| / (|n| |r|), with the surface normal n taken from the
organised image, n = (P[u+1] - P[u-1]) x (P[v+1] - P[v-1]) (azimuth wraps, elevation does
not). Along azimuth the neighbour is the nearest occupied pixel within MAX_COLUMN_GAP columns,
because rings with fewer returns than columns leave every other pixel empty. A central
difference needs both neighbours and a range profile that is smooth through the centre:
2 |r_interp - r[0]| <= max_depth_jump * r[0], r_interp being the range linearly interpolated
from the two neighbours (|r[+1] - 2 r[0] + r[-1]| for adjacent ones). That second difference
is ~0 on any plane, also on ground at grazing angles where adjacent rows differ by 10-30 % in
range, but equals the jump at an object edge and twice it on thin objects. Failing that, a
one-sided difference P[side] - P[0] to the neighbour with the smaller range jump is used if
that jump is <= max_depth_jump * r[0] (edge pixels, top and bottom rows). Creases (a wall
meeting the ground) have no range jump and get a blend of both normals within ~1 pixel.
Every point takes the normal of the pixel it falls in, with its own ray direction, unless its
range differs from the pixel owner's by more than max_depth_jump * r (another surface).
The rest get a local PCA normal from up to KNN_NEIGHBOURS neighbours within KNN_RADIUS_M (at
least KNN_MIN_NEIGHBOURS, not collinear as points along one ring are), and finally the frame
median of the computed cosines (0.5 if there is none). `Incidence.source` records which.
"""

from __future__ import annotations

__all__ = [
    "Incidence", "IncidenceSource", "Modalities", "RangeImage", "channels",
    "compute_modalities", "incidence", "incidence_cos", "physics_intensity", "project",
    "range_m", "MIN_RANGE_M",
]  # fmt: skip

import enum
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError, InvalidPointsError
from lads.physics.image_kernels import image_normals, on_pixel_surface, pixel_normal_cos
from lads.physics.knn_normals import neighbour_cos
from lads.physics.masked_median import masked_median
from lads.physics.materials import reflectance_for_labels
from lads.physics.projection import (
    MIN_RANGE_M,
    RangeImage,
    channels,
    channels_of,
    checked_xyz,
    organise,
    project,
    range_m,
)
from lads.sensors.profile import SensorProfile

RANGE_FLOOR_M = 1e-3  # physics_intensity clamps ranges below this (1/R^n would blow up)
DEFAULT_MAX_DEPTH_JUMP = 0.1  # relative; see the module docstring
KNN_NEIGHBOURS = 10
KNN_RADIUS_M = 1.0
KNN_MIN_NEIGHBOURS = 5
# PCA patches whose middle eigenvalue is below this fraction of the largest are lines (one
# ring), whose smallest-eigenvalue direction is not a surface normal.
KNN_MIN_PLANARITY = 0.02
FALLBACK_COS = 0.5
# Azimuth neighbours may sit up to this many columns away: rings with fewer returns than
# columns (KITTI: 1126-2156 points per ring in 2048 columns) leave every other pixel empty.
MAX_COLUMN_GAP = 2

FloatArray = npt.NDArray[np.float32]


class IncidenceSource(enum.IntEnum):
    """Where a point's incidence cosine came from."""

    IMAGE = 0  # normal of the organised range image
    NEIGHBOURS = 1  # PCA normal of its k nearest neighbours
    MEDIAN = 2  # frame median (0.5 if nothing could be computed)


@dataclass(frozen=True, slots=True)
class Incidence:
    """cos_incidence (N,) float32 in [0, 1] and source (N,) int8 `IncidenceSource` codes."""

    cos: FloatArray
    source: npt.NDArray[np.int8]


@dataclass(frozen=True, slots=True)
class Modalities:
    """Per-point inputs of the intensity models, all (N,) in input point order.

    Attributes:
        range_m: float32 range in m.
        channel: int64 laser channel, 0 = lowest beam.
        cos_incidence: float32 cosine of the incidence angle, in [0, 1].
        incidence_source: int8 `IncidenceSource` code of each cosine.
        reflectance: float32 material reflectance at 905 nm, unitless.
        physics_intensity: float32 rho cos(theta) / R^n exp(-2 alpha R), in m^-n.
    """

    range_m: FloatArray
    channel: npt.NDArray[np.int64]
    cos_incidence: FloatArray
    incidence_source: npt.NDArray[np.int8]
    reflectance: FloatArray
    physics_intensity: FloatArray


def incidence(
    xyz: npt.ArrayLike,
    profile: SensorProfile,
    *,
    channel: npt.ArrayLike | None = None,
    image: RangeImage | None = None,
    max_depth_jump: float = DEFAULT_MAX_DEPTH_JUMP,
) -> Incidence:
    """Incidence cosine of every point and where it came from (see the module docstring).

    Args:
        xyz: (N, 3) coordinates in m.
        profile: sensor profile used to build the range image.
        channel: optional (N,) channel per point, used to build the image.
        image: optional `project(xyz, ...)` result for these very points (then `channel`
            must be None).
        max_depth_jump: relative range tolerance (> 0) for edges, see the module docstring.

    Returns:
        Incidence with cos (N,) float32 in [0, 1] and source (N,) int8.

    Raises:
        InvalidPointsError: bad xyz, or an image built from another cloud.
        ConfigError: both channel and image given, or max_depth_jump <= 0.
    """
    xyz64, r = checked_xyz(xyz)
    if image is not None and channel is not None:
        raise ConfigError("incidence: pass either channel or a prebuilt image, not both.")
    if not max_depth_jump > 0:
        raise ConfigError(f"max_depth_jump = {max_depth_jump}; expected a relative value > 0.")
    if image is None:
        chan = channels_of(xyz64, profile, channel)
        image = organise(xyz64, r, chan, profile.channels, profile.range_image_width)
    elif image.row.shape != (len(xyz64),):
        raise InvalidPointsError(
            f"image: built from {image.row.shape[0]} points, but xyz has {len(xyz64)}; "
            "project the same cloud."
        )
    return _incidence(xyz64, r, image, max_depth_jump)


def incidence_cos(
    xyz: npt.ArrayLike,
    profile: SensorProfile,
    *,
    channel: npt.ArrayLike | None = None,
    image: RangeImage | None = None,
    max_depth_jump: float = DEFAULT_MAX_DEPTH_JUMP,
) -> FloatArray:
    """(N,) float32 incidence cosine in [0, 1] for every point; `incidence` without sources."""
    return incidence(xyz, profile, channel=channel, image=image, max_depth_jump=max_depth_jump).cos


def physics_intensity(
    reflectance: npt.ArrayLike,
    cos_incidence: npt.ArrayLike,
    range_m: npt.ArrayLike,
    *,
    range_exponent: float = 1.0,
    extinction_per_m: float = 0.0,
) -> FloatArray:
    """Physics intensity I = rho cos(theta) / R^n * exp(-2 alpha R) (docs/physics.md §10.1).

    ReaLiTy's clear-weather I_phy = MR cos(theta) / r has n = 1 and alpha = 0; the
    adverse-weather form adds two-way Beer-Lambert extinction. The extended-target radar
    equation has n = 2 (docs/physics.md §9), real sensors n_eff 1-3, so n is a parameter.

    Args:
        reflectance: (N,) unitless, >= 0.
        cos_incidence: (N,) in [0, 1].
        range_m: (N,) in m, >= 0. Ranges below RANGE_FLOOR_M (1 mm) are clamped to it:
            such returns are unphysical (e.g. nuScenes ego-body points at 1e-5 m) but must
            keep a finite value, because points are never dropped.
        range_exponent: n >= 0.
        extinction_per_m: alpha >= 0 in 1/m.

    Returns:
        (N,) float32 intensity in m^-n (relative units).

    Raises:
        InvalidPointsError: shapes differ, NaN/inf, or values outside the ranges above.
        ConfigError: negative or non-finite range_exponent or extinction_per_m.
    """
    for name, value in (("range_exponent", range_exponent), ("extinction_per_m", extinction_per_m)):
        if not (np.isfinite(value) and value >= 0):
            raise ConfigError(f"{name} = {value}; expected a finite value >= 0.")
    rho, cos, rng = (np.asarray(a, dtype=np.float64) for a in (reflectance, cos_incidence, range_m))
    if not rho.shape == cos.shape == rng.shape:
        raise InvalidPointsError(
            f"physics_intensity: shapes differ: reflectance {rho.shape}, cos_incidence "
            f"{cos.shape}, range_m {rng.shape}."
        )
    for name, arr, low, high in (
        ("reflectance", rho, 0.0, np.inf),
        ("cos_incidence", cos, 0.0, 1.0),
        ("range_m", rng, 0.0, np.inf),
    ):
        bad = int(np.count_nonzero(~((arr >= low) & (arr <= high))))  # NaN fails both
        if bad:
            raise InvalidPointsError(
                f"physics_intensity: {bad} {name} values are NaN or outside [{low}, {high}]."
            )
    rng = np.maximum(rng, RANGE_FLOOR_M)
    out: npt.NDArray[np.float64] = rho * cos * rng**-range_exponent
    out *= np.exp(-2.0 * extinction_per_m * rng)
    return out.astype(np.float32)


def compute_modalities(
    xyz: npt.ArrayLike,
    labels: npt.ArrayLike,
    label_set: str,
    profile: SensorProfile,
    *,
    ring: npt.ArrayLike | None = None,
    range_exponent: float = 1.0,
    extinction_per_m: float = 0.0,
) -> Modalities:
    """All per-point modalities of one frame in one call.

    Args:
        xyz: (N, 3) coordinates in m, sensor frame.
        labels: (N,) integer class labels of `label_set` (instance bits allowed).
        label_set: one of `lads.physics.materials.LABEL_SETS`.
        profile: sensor profile of the frame.
        ring: optional (N,) ring column (0 = lowest beam); default nearest elevation.
        range_exponent, extinction_per_m: see `physics_intensity`.

    Returns:
        Modalities, every array (N,) in input order; an empty frame gives empty arrays.

    Raises:
        InvalidPointsError: bad xyz or ring, or labels of another length.
        InputDataError: negative labels. ConfigError: unknown label set or bad parameters.
    """
    xyz64, r = checked_xyz(xyz)
    label_arr = np.asarray(labels)
    if label_arr.shape != (len(xyz64),):
        raise InvalidPointsError(
            f"labels: shape {label_arr.shape}, expected ({len(xyz64)},), one per point."
        )
    chan = channels_of(xyz64, profile, ring)
    image = organise(xyz64, r, chan, profile.channels, profile.range_image_width)
    inc = _incidence(xyz64, r, image, DEFAULT_MAX_DEPTH_JUMP)
    rho = reflectance_for_labels(label_arr, label_set)
    range32 = r.astype(np.float32)
    phys = physics_intensity(
        rho, inc.cos, r, range_exponent=range_exponent, extinction_per_m=extinction_per_m
    )
    return Modalities(range32, chan, inc.cos, inc.source, rho, phys)


def _incidence(
    xyz64: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
    image: RangeImage,
    max_depth_jump: float,
) -> Incidence:
    n_points = len(xyz64)
    source = np.full(n_points, IncidenceSource.MEDIAN, dtype=np.int8)
    if n_points == 0:
        return Incidence(np.zeros(0, dtype=np.float32), source)
    range_img = image.range_m.astype(np.float64)
    normal, ok = image_normals(
        image.xyz.astype(np.float64),
        range_img,
        image.index >= 0,
        MAX_COLUMN_GAP,
        float(max_depth_jump),
    )
    use = on_pixel_surface(
        ok, range_img, image.row, image.col, np.ascontiguousarray(r), float(max_depth_jump)
    )
    cos = pixel_normal_cos(normal, image.row, image.col, np.ascontiguousarray(xyz64), use)
    source[use] = IncidenceSource.IMAGE

    rest = np.flatnonzero(~use)
    if rest.size:
        knn_cos, found = _neighbour_cos(xyz64, rest)
        cos[rest[found]] = knn_cos[found]
        source[rest[found]] = IncidenceSource.NEIGHBOURS
    computed = source != IncidenceSource.MEDIAN
    if not computed.all():
        cos[~computed] = masked_median(cos, computed) if computed.any() else FALLBACK_COS
    return Incidence(np.clip(cos, 0.0, 1.0).astype(np.float32), source)


def _neighbour_cos(
    xyz64: npt.NDArray[np.float64], query: npt.NDArray[np.intp]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """PCA-normal cosine for the `query` points; (M,) cos and (M,) found flags."""
    return neighbour_cos(
        xyz64,
        query,
        k=KNN_NEIGHBOURS,
        radius_m=KNN_RADIUS_M,
        min_neighbours=KNN_MIN_NEIGHBOURS,
        min_planarity=KNN_MIN_PLANARITY,
    )
