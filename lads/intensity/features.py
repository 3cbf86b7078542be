"""Range-image inputs of the intensity models, built from one frame's points.

Pure numpy, no I/O. A frame is organised in its *own* sensor geometry (rows = laser channel,
columns = azimuth; `lads.physics.projection`), never in another sensor's grid (docs/physics.md
§10.7 item 3). Every pixel owned by a point carries the physics modalities of that point:

    ln_range       ln(R / 1 m)
    cos_incidence  cos(theta) in [0, 1]
    reflectance    material reflectance at 905 nm from the labels (0.20 "unknown" without)
    ln_physics     ln(I_P + PHYSICS_FLOOR), I_P = rho cos(theta) / R^n exp(-2 alpha R)
    elevation      the row's laser elevation in degrees / 30 (per-laser gain is a sensor
                   effect; degrees rather than row numbers keep it meaningful across sensors)
    particle       1 for weather particle returns, else 0
    mask           1 where a point owns the pixel
    ln_geometry    ln(cos(theta) / R^n exp(-2 alpha R) + GEOMETRY_FLOOR): I_P per unit
                   reflectance, so I_P can be rebuilt for a predicted reflectance (cycle)
    material       1 + the material's index in `lads.physics.materials.material_names()`
                   (0 is an empty pixel): which material, not only its reflectance. A
                   sensor answers materials of similar diffuse reflectance very differently
                   (glossy car paint, retro-reflective sheeting, white lane paint); a scalar
                   reflectance cannot carry that, a learned per-material embedding can.
    rain/snow/fog  one-hot weather style, broadcast (weather models only)

Empty pixels hold 0 in every channel. I_P is computed from materials, incidence and range,
never from a measured intensity (docs/physics.md §10.7 item 5). The measured intensity of a frame
(when it has one) becomes the target image, as reflectivity (encoded / full scale).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Collection
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError, InvalidPointsError
from lads.physics.materials import (
    default_material,
    material_names,
    reflectance_and_material_for_labels,
)
from lads.physics.modalities import _incidence, physics_intensity
from lads.physics.projection import RangeImage, channels_of, checked_xyz, organise
from lads.physics.result import Outcome
from lads.sensors.profile import SensorProfile

FEATURE_VERSION = "2"  # 2: the material channel
STYLES: tuple[str, ...] = ("rain", "snow", "fog")
BASE_CHANNELS: tuple[str, ...] = (
    "ln_range", "cos_incidence", "reflectance", "ln_physics", "elevation", "particle", "mask",
    "ln_geometry", "material",
)  # fmt: skip
# Channels z-scored with statistics from the training cache; the rest are already O(1).
NORMALISED_CHANNELS: tuple[str, ...] = ("ln_range", "cos_incidence", "reflectance", "ln_physics")
UNKNOWN_REFLECTANCE = 0.20  # docs/physics.md §10.2 "unknown (default)"
PHYSICS_FLOOR = 1e-6  # keeps ln(I_P) finite for cos(theta) = 0 or rho = 0
GEOMETRY_FLOOR = 1e-6
DEFAULT_DEPTH_JUMP = 0.1
ELEVATION_SCALE_DEG = 30.0

FloatArray = npt.NDArray[np.float32]


def channel_names(styles: bool) -> tuple[str, ...]:
    """Input channel names of a sensor model (styles=False) or a weather model (True)."""
    return BASE_CHANNELS + (STYLES if styles else ())


@dataclass(frozen=True)
class FrameImage:
    """One frame as model input, plus what is needed to give every point its value.

    Attributes:
        inputs: (C, H, W) float32 raw channels named by `channels` (not yet normalised),
            each pixel its owner's column of `point_inputs`; built on first use (a pointwise
            generator never needs it).
        channels: channel names of `inputs`.
        target: (H, W) float32 measured reflectivity of the pixel owner (encoded intensity /
            full scale), 0 where empty; None when the frame has no measured intensity.
        labelled: reflectance came from labels (False: every point has UNKNOWN_REFLECTANCE).
        image: the projection (owner index per pixel, row and column of every point).
        physics: (N,) float32 I_P of every point, in m^-n; computed on first use (a
            pointwise generator that does not read it never needs it).
        reflectance: (N,) float32 material reflectance of every point.
        cos_incidence: (N,) float32 cosine of every point.
        range_m: (N,) float32 range of every point.
        elevation_deg: (N,) float32 table elevation of every point's beam (its channel in
            the frame's profile), degrees.
        material: (N,) int64 index of every point's material in `material_names()`.
        point_inputs: (C, N) float32 the channels of `inputs` for every point, owner or
            not (a pixel of `inputs` holds its owner's column).
    """

    channels: tuple[str, ...]
    target: FloatArray | None
    labelled: bool
    image: RangeImage
    reflectance: FloatArray
    cos_incidence: FloatArray
    range_m: FloatArray
    elevation_deg: FloatArray
    material: npt.NDArray[np.int64]
    point_inputs: FloatArray
    physics_of: Callable[[], FloatArray] = field(repr=False, compare=False)

    @functools.cached_property
    def physics(self) -> FloatArray:
        """(N,) float32 I_P of every point, in m^-n (see the class docstring)."""
        return self.physics_of()

    @property
    def mask(self) -> npt.NDArray[np.bool_]:
        """(H, W) bool, True where a point owns the pixel."""
        return self.image.index >= 0

    @functools.cached_property
    def inputs(self) -> FloatArray:
        """(C, H, W) float32, see the class docstring."""
        owners = self.image.index.reshape(-1)
        occupied = owners >= 0
        planes = np.zeros((len(self.channels), owners.size), dtype=np.float32)
        planes[:, occupied] = self.point_inputs[:, owners[occupied]]
        return planes.reshape(len(self.channels), *self.image.index.shape)


def frame_image(
    xyz: npt.ArrayLike,
    profile: SensorProfile,
    *,
    labels: npt.ArrayLike | None = None,
    label_set: str | None = None,
    ring: npt.ArrayLike | None = None,
    intensity: npt.ArrayLike | None = None,
    outcome: npt.ArrayLike | None = None,
    particle: npt.ArrayLike | None = None,
    style: str | None = None,
    styles: bool = False,
    range_exponent: float = 1.0,
    extinction_per_m: float = 0.0,
    width: int | None = None,
    only: Collection[str] | None = None,
) -> FrameImage:
    """Organise one frame and compute its model inputs.

    Args:
        xyz: (N, 3) coordinates in m, sensor frame; no point at zero range.
        profile: the frame's own sensor profile (rows, elevations, intensity encoding).
        labels: (N,) class labels of `label_set`, or None (then reflectance is unknown).
        label_set: material label set of the labels (`lads.physics.materials.LABEL_SETS`).
        ring: optional (N,) ring column, 0 = lowest beam; default nearest elevation.
        intensity: optional (N,) measured intensity in the profile's encoding -> `target`.
        outcome: optional (N,) `Outcome` codes; PARTICLE marks particle returns.
        particle: optional (N,) bool particle flags (e.g. WADS label 110); OR-ed with outcome.
        style: weather style of the frame (one of STYLES) or None for clear weather.
        styles: add the one-hot style channels (weather models).
        range_exponent: n of I_P (paper: 1).
        extinction_per_m: alpha of I_P in 1/m (0 in clear weather).
        width: azimuth bins; default the profile's range_image_width.
        only: the channels a model reads (the others stay 0 in `point_inputs`); None: all.

    Returns:
        FrameImage.

    Raises:
        InvalidPointsError: bad xyz, ring, labels, intensity or flags.
        ConfigError: unknown style or label set, a style without style channels, bad width.
    """
    r, chan, image, cos = _organised(xyz, profile, ring, style, styles, width)
    return _frame_of(
        r,
        chan,
        image,
        cos,
        profile,
        labels=labels,
        label_set=label_set,
        intensity=intensity,
        outcome=outcome,
        particle=particle,
        style=style,
        styles=styles,
        range_exponent=range_exponent,
        extinction_per_m=extinction_per_m,
        only=only,
    )


def _organised(
    xyz: npt.ArrayLike,
    profile: SensorProfile,
    ring: npt.ArrayLike | None,
    style: str | None,
    styles: bool,
    width: int | None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], RangeImage, FloatArray]:
    """A checked frame's (N,) range m, (N,) channel, range image and (N,) float32 cos."""
    xyz64, r = checked_xyz(xyz)
    w = _checked_width(profile, style, styles, width)
    chan = channels_of(xyz64, profile, ring)
    image = organise(xyz64, r, chan, profile.channels, w)
    cos = _incidence(xyz64, r, image, DEFAULT_DEPTH_JUMP).cos
    return r, chan, image, cos


def _frame_of(
    r: npt.NDArray[np.float64],
    chan: npt.NDArray[np.int64],
    image: RangeImage,
    cos: FloatArray,
    profile: SensorProfile,
    *,
    labels: npt.ArrayLike | None,
    label_set: str | None,
    intensity: npt.ArrayLike | None,
    outcome: npt.ArrayLike | None,
    particle: npt.ArrayLike | None,
    style: str | None,
    styles: bool,
    range_exponent: float,
    extinction_per_m: float,
    only: Collection[str] | None = None,
) -> FrameImage:
    """The FrameImage of an `_organised` frame: point modalities, channels and target."""
    n = len(r)
    rho, material = _reflectance_and_material(n, labels, label_set)
    phys = functools.cache(
        lambda: physics_intensity(
            rho, cos, r, range_exponent=range_exponent, extinction_per_m=extinction_per_m
        )
    )
    is_particle = _particle_flags(n, outcome, particle)

    names = channel_names(styles)
    elevation_deg = np.asarray(profile.elevation_deg, dtype=np.float64)[chan]
    columns = _point_columns(
        names,
        r,
        cos,
        rho,
        phys,
        is_particle,
        material,
        elevation_deg,
        style,
        range_exponent=range_exponent,
        extinction_per_m=extinction_per_m,
        only=only,
    )
    return FrameImage(
        channels=names,
        target=None if intensity is None else _target(intensity, n, profile, image.index),
        labelled=labels is not None,
        image=image,
        physics_of=phys,
        reflectance=rho.astype(np.float32),
        cos_incidence=cos.astype(np.float32),
        range_m=r.astype(np.float32),
        elevation_deg=np.asarray(profile.elevation_deg, dtype=np.float32)[chan],
        material=material,
        point_inputs=columns,
    )


def _point_columns(
    names: tuple[str, ...],
    r: npt.NDArray[np.float64],
    cos: npt.NDArray[np.float32],
    rho: npt.NDArray[np.float32],
    phys: Callable[[], npt.NDArray[np.float32]],
    is_particle: npt.NDArray[np.bool_],
    material: npt.NDArray[np.int64],
    elevation_deg: npt.NDArray[np.float64],
    style: str | None,
    *,
    range_exponent: float,
    extinction_per_m: float,
    only: Collection[str] | None = None,
) -> npt.NDArray[np.float32]:
    """(C, N) float32 model inputs of the N points, one row per channel of `names`: range
    (m), incidence cosine, reflectance, physics intensity, material, elevation (deg) and
    flags, as the channels' docs in this module say. Channels outside `only` (when given)
    are left 0: the model never reads them."""
    n = r.size
    per_point: dict[str, Callable[[], npt.ArrayLike]] = {
        "ln_range": lambda: np.log(r),
        "cos_incidence": lambda: cos,
        "reflectance": lambda: rho,
        "ln_physics": lambda: np.log(phys().astype(np.float64) + PHYSICS_FLOOR),
        "particle": lambda: is_particle.astype(np.float32),
        "material": lambda: (material + 1).astype(np.float32),
        "ln_geometry": lambda: np.log(
            physics_intensity(
                np.ones(n),
                cos,
                r,
                range_exponent=range_exponent,
                extinction_per_m=extinction_per_m,
            ).astype(np.float64)
            + GEOMETRY_FLOOR
        ),
        "elevation": lambda: elevation_deg / ELEVATION_SCALE_DEG,
        "mask": lambda: np.ones(n, dtype=np.float32),
    }
    if style is not None:
        per_point[style] = lambda: np.ones(n, dtype=np.float32)
    columns = np.zeros((len(names), n), dtype=np.float32)
    for name, values in per_point.items():
        if only is None or name in only:
            columns[names.index(name)] = values()
    return columns


def _checked_width(
    profile: SensorProfile, style: str | None, styles: bool, width: int | None
) -> int:
    """The range image's azimuth bins (default the profile's), after checking the style.

    Raises:
        ConfigError: unknown style, a style without style channels, or a bad width.
    """
    if style is not None and style not in STYLES:
        raise ConfigError(f"weather style {style!r}: expected one of {', '.join(STYLES)}.")
    if style is not None and not styles:
        raise ConfigError(f"weather style {style!r} given to a model without style channels.")
    w = profile.range_image_width if width is None else int(width)
    if w < 8 or w % 4:
        raise ConfigError(f"range-image width {w}: expected a multiple of 4, at least 8.")
    return w


def _reflectance_and_material(
    n: int, labels: npt.ArrayLike | None, label_set: str | None
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]:
    """(N,) reflectance and (N,) material index of the points' labels; without labels the
    unknown reflectance and the default material.

    Raises:
        ConfigError: labels without a label set.
        InvalidPointsError: labels of the wrong shape.
    """
    if labels is None:
        rho = np.full(n, UNKNOWN_REFLECTANCE, dtype=np.float32)
        material = np.full(n, material_names().index(default_material()), dtype=np.int64)
        return rho, material
    if label_set is None:
        raise ConfigError("labels given without a label_set; pass the dataset's label set.")
    label_arr = np.asarray(labels)
    if label_arr.shape != (n,):
        raise InvalidPointsError(f"labels: shape {label_arr.shape}, expected ({n},).")
    return reflectance_and_material_for_labels(label_arr, label_set)


def _target(
    intensity: npt.ArrayLike, n: int, profile: SensorProfile, owners: npt.NDArray[np.int64]
) -> npt.NDArray[np.float32]:
    """The measured reflectivity per pixel (0 where no point), float32, of (N,) intensities
    in the profile's encoding; `owners` is the image's point index per pixel (-1: none).

    Raises:
        InvalidPointsError: intensities of the wrong shape or out of the encoding's range.
    """
    values = np.asarray(intensity, dtype=np.float32)
    if values.shape != (n,):
        raise InvalidPointsError(f"intensity: shape {values.shape}, expected ({n},).")
    profile.intensity.validate(values, "intensity")
    refl = profile.intensity.to_reflectivity(values).astype(np.float32)
    return np.where(owners >= 0, refl[np.maximum(owners, 0)], 0.0).astype(np.float32)


def _particle_flags(
    n: int, outcome: npt.ArrayLike | None, particle: npt.ArrayLike | None
) -> npt.NDArray[np.bool_]:
    flags = np.zeros(n, dtype=bool)
    for name, arr in (("outcome", outcome), ("particle", particle)):
        if arr is None:
            continue
        values = np.asarray(arr)
        if values.shape != (n,):
            raise InvalidPointsError(f"{name}: shape {values.shape}, expected ({n},).")
        flags |= values == Outcome.PARTICLE if name == "outcome" else values.astype(bool)
    return flags
