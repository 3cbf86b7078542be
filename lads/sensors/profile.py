"""Load and validate sensor profiles (`lads/sensors/*.yaml`).

A profile is data, not code: channel geometry, optics and the intensity encoding of one
LiDAR as it appears in one dataset. Channel ids run from the lowest beam (0) upwards, which
is the nuScenes ring convention; datasets without a ring column get channels by nearest
elevation (`SensorProfile.channel_of`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import yaml

from lads.errors import IntensityEncodingError, SensorProfileError
from lads.resources import sensors_dir
from lads.sensors.lookup import elevation_positions


@functools.lru_cache(maxsize=16)
def _encoding_levels(step: float, max_value: float) -> npt.NDArray[np.float32]:
    count = int(math.floor(max_value / step + 1e-9)) + 1
    levels = (np.arange(count, dtype=np.float64) * step).astype(np.float32)
    levels.flags.writeable = False
    return levels


@dataclass(frozen=True, slots=True)
class IntensityEncoding:
    """How a dataset stores intensity, and how that maps to reflectivity.

    Attributes:
        kind: "unit" (float remission in [0, 1), e.g. SemanticKITTI) or "byte" (integer
            values 0-255 stored as float, e.g. nuScenes, WADS).
        reflectivity_full_scale: encoded value that stands for a diffuse (Lambertian)
            reflectivity of 1.0. Larger values (retro-reflectors) map to reflectivity > 1.
        step: quantisation step of the stored values (0.01 or 1.0).
        max_value: largest value the encoding can hold (0.99 or 255).
    """

    kind: Literal["unit", "byte"]
    reflectivity_full_scale: float
    step: float
    max_value: float

    def to_reflectivity(self, intensity: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Encoded intensity (N,) -> reflectivity (N,) float64, linear, unitless."""
        return np.asarray(intensity, dtype=np.float64) / self.reflectivity_full_scale

    def from_reflectivity(self, reflectivity: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Reflectivity (N,) -> encoded intensity (N,) float32, rounded to `step`, clipped.

        Values come from a table of the encoding's levels computed in float64 and cast once,
        so they are the very float32 numbers the datasets store (KITTI's 0.29 is
        float32(0.29), not float32(29) * float32(0.01), which differs in the last bit).
        """
        scale, levels = self.compiled
        steps = np.asarray(reflectivity, dtype=np.float32) * scale
        np.rint(steps, out=steps)
        np.clip(steps, 0.0, levels.size - 1, out=steps)
        return levels[steps.astype(np.intp)]

    @property
    def compiled(self) -> tuple[np.float32, npt.NDArray[np.float32]]:
        """(scale, levels) of `from_reflectivity` for compiled loops: the encoded value of
        rho is levels[clip(rint(float32(rho) * scale))]."""
        return np.float32(self.reflectivity_full_scale / self.step), _encoding_levels(
            self.step, self.max_value
        )

    @property
    def detection_floor(self) -> float:
        """Reflectivity assumed for a stored 0: half a quantisation step.

        A point stored with intensity 0 was detected, so its true reflectivity is positive
        but below half a step; half a step is the midpoint of that interval.
        """
        return 0.5 * self.step / self.reflectivity_full_scale

    def validate(self, intensity: npt.NDArray[Any], what: str) -> None:
        """Raise IntensityEncodingError if any value lies outside [0, max_value], or if a
        byte encoding is given values that are all in [0, 1] and not all whole numbers (a
        unit-encoded scan fits the byte range but holds no byte code)."""
        if intensity.size == 0:
            return
        all_finite = bool(np.isfinite(intensity).all())
        finite = intensity if all_finite else intensity[np.isfinite(intensity)]
        low, high = float(finite.min(initial=0.0)), float(finite.max(initial=0.0))
        if not all_finite or low < 0.0 or high > self.max_value * (1 + 1e-6):
            raise IntensityEncodingError(
                f"{what}: intensities span [{low:g}, {high:g}]"
                f"{'' if all_finite else ' and include NaN/inf'}, but the '{self.kind}' "
                f"encoding holds values in [0, {self.max_value:g}]. Pass the sensor profile "
                "that matches the data (e.g. 'hdl64e' for SemanticKITTI remission in [0, 1), "
                "'hdl32e' for nuScenes 0-255) or rescale the intensities first."
            )
        if self.kind == "byte" and high <= 1.0 and not np.array_equal(finite, np.rint(finite)):
            raise IntensityEncodingError(
                f"{what}: every intensity lies in [0, 1] and some are fractions, but the "
                f"'byte' encoding stores whole numbers 0-{self.max_value:g}: the values look "
                "unit-encoded (e.g. SemanticKITTI remission). Pass the sensor profile that "
                "matches the data (e.g. 'hdl64e'), or its 0-255 codes."
            )


@dataclass(frozen=True, slots=True)
class DetectionLimit:
    """The sensor's hard-target detection limit (docs/physics.md §9.7).

    Attributes:
        reflectivity: rho_lim, a diffuse target reflectivity (quoted by a datasheet, or the
            reference of a measured limit).
        range_m: r_lim, the range at which such a target is detected (half the time), m.
        spread_ln: s, width of the detection probability curve Phi((ln P - ln P_lim) / s) in
            ln-power units (detection rises from 10 % to 90 % over a factor exp(2.56 s)).
    """

    reflectivity: float
    range_m: float
    spread_ln: float

    @property
    def power(self) -> float:
        """P_lim = rho_lim / r_lim^2, normalised power (reflectivity / m^2)."""
        return self.reflectivity / self.range_m**2


@dataclass(frozen=True, slots=True)
class SensorProfile:
    """One LiDAR as recorded in one dataset.

    Attributes:
        name: profile id, also the YAML file stem.
        description: sensor model and dataset.
        channels: number of laser channels (beams).
        elevation_deg: (channels,) elevation of each channel in degrees, channel 0 lowest,
            strictly increasing.
        elevation_method: how the elevations were obtained (measured on which files, how).
        vertical_fov_deg: (lowest, highest) elevation in degrees that the range image spans.
        range_image_width: azimuth bins of the range image.
        wavelength_nm: laser wavelength in nm.
        beam_divergence_mrad: full-angle beam divergence in mrad.
        min_range_m: bistatic minimum range in m (R1): the transmitter and receiver fields
            of view start to overlap here; nothing nearer is detected.
        overlap_full_m: range of full transmitter/receiver overlap in m (R2 >= R1); between
            R1 and R2 the received power scales linearly with the overlap, which bright hard
            targets survive but faint particle and fog returns mostly do not.
        max_range_m: maximum range in m.
        range_accuracy_m: one-sigma range accuracy in m at the detection threshold.
        detection: the detection limit, measured or from the datasheet (`DetectionLimit`).
        pulse_width_ns: full width at half power of the laser pulse, ns; volume (fog)
            returns scale with it, hard-target returns do not.
        intensity: the dataset's intensity encoding.
        has_ring_column: scans carry a per-point ring (channel) column.
        sources: citations for the numbers above.
        sweep_period_s: time of one revolution in the dataset the profile describes, s
            (1 / the spin rate); None when unknown. Motion distortion reads it.
        forward_azimuth_deg: azimuth atan2(y, x) of the vehicle's forward direction in the
            sensor frame, degrees (0 when x points forward, 90 for nuScenes LIDAR_TOP,
            whose y points forward); None when unknown.
        native_format: the dataset format the sensor's scans are natively recorded in, a
            reader name of `lads.readers.READERS` ("nuscenes" for the HDL-32E); its reader's
            `columns` are the sensor's native point record (`--point-format target`). None
            when unknown.
    """

    name: str
    description: str
    channels: int
    elevation_deg: tuple[float, ...]
    elevation_method: str
    vertical_fov_deg: tuple[float, float]
    range_image_width: int
    wavelength_nm: float
    beam_divergence_mrad: float
    min_range_m: float
    overlap_full_m: float
    max_range_m: float
    range_accuracy_m: float
    detection: DetectionLimit
    pulse_width_ns: float
    intensity: IntensityEncoding
    has_ring_column: bool
    sources: tuple[str, ...]
    sweep_period_s: float | None = None
    forward_azimuth_deg: float | None = None
    native_format: str | None = None

    @property
    def beam_divergence_rad(self) -> float:
        return self.beam_divergence_mrad * 1e-3

    @property
    def wavelength_m(self) -> float:
        return self.wavelength_nm * 1e-9

    def channel_of(self, xyz: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.int64]:
        """Nearest channel for each point by elevation: (N, 3) m -> (N,) int64 in [0, channels)."""
        table = np.asarray(self.elevation_deg, dtype=np.float64)
        midpoints = 0.5 * (table[1:] + table[:-1])
        return elevation_positions(np.asarray(xyz, dtype=np.float64), midpoints)


def available_profiles() -> list[str]:
    """Names of the profiles shipped with lads."""
    return sorted(p.stem for p in sensors_dir().glob("*.yaml"))


@functools.lru_cache(maxsize=32)
def load_profile(name_or_path: str | Path) -> SensorProfile:
    """Load a profile by shipped name ("hdl64e") or by YAML path, validated.

    Raises:
        SensorProfileError: unknown name, unreadable file, missing or unknown keys, or
            inconsistent values; the message names the file and the key.
    """
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = sensors_dir() / f"{name_or_path}.yaml"
    if not path.is_file():
        raise SensorProfileError(
            f"sensor profile '{name_or_path}' not found (looked for {path}); "
            f"shipped profiles: {', '.join(available_profiles())}, or pass a YAML path."
        )
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise SensorProfileError(f"{path}: cannot read YAML ({exc}); fix the file.") from exc
    if not isinstance(raw, dict):
        raise SensorProfileError(f"{path}: expected a mapping of profile keys at top level.")
    return _build(raw, path)


# Keys a profile may leave out (older or user-written profiles); the stages that need them
# say so when they are missing.
_OPTIONAL_NUMBERS = ("sweep_period_s", "forward_azimuth_deg")
_OPTIONAL_KEYS = (*_OPTIONAL_NUMBERS, "native_format")


def _build(raw: dict[str, Any], path: Path) -> SensorProfile:
    expected = {f.name for f in fields(SensorProfile)}
    unknown, missing = set(raw) - expected, expected - set(raw) - set(_OPTIONAL_KEYS)
    if unknown or missing:
        raise SensorProfileError(
            f"{path}: unknown keys {sorted(unknown)}, missing keys {sorted(missing)}; "
            f"a profile has exactly: {sorted(expected)}."
        )
    try:
        enc = IntensityEncoding(**raw["intensity"])
        profile = SensorProfile(
            name=str(raw["name"]),
            description=str(raw["description"]),
            channels=int(raw["channels"]),
            elevation_deg=tuple(float(v) for v in raw["elevation_deg"]),
            elevation_method=str(raw["elevation_method"]),
            vertical_fov_deg=(float(raw["vertical_fov_deg"][0]), float(raw["vertical_fov_deg"][1])),
            range_image_width=int(raw["range_image_width"]),
            wavelength_nm=float(raw["wavelength_nm"]),
            beam_divergence_mrad=float(raw["beam_divergence_mrad"]),
            min_range_m=float(raw["min_range_m"]),
            overlap_full_m=float(raw["overlap_full_m"]),
            max_range_m=float(raw["max_range_m"]),
            range_accuracy_m=float(raw["range_accuracy_m"]),
            detection=DetectionLimit(**{k: float(v) for k, v in raw["detection"].items()}),
            pulse_width_ns=float(raw["pulse_width_ns"]),
            intensity=enc,
            has_ring_column=bool(raw["has_ring_column"]),
            sources=tuple(str(s) for s in raw["sources"]),
            **{k: float(raw[k]) for k in _OPTIONAL_NUMBERS if raw.get(k) is not None},
            native_format=None if raw.get("native_format") is None else str(raw["native_format"]),
        )
    except (TypeError, ValueError, KeyError, IndexError, AttributeError) as exc:
        raise SensorProfileError(
            f"{path}: malformed value ({exc}); see lads/sensors/*.yaml."
        ) from exc
    _check(profile, path)
    return profile


def _check(p: SensorProfile, path: Path) -> None:
    problems = []
    elev = np.asarray(p.elevation_deg)
    if p.name != path.stem and path.parent == sensors_dir():
        problems.append(f"name '{p.name}' differs from the file stem '{path.stem}'")
    if len(elev) != p.channels:
        problems.append(f"{len(elev)} elevation_deg values for {p.channels} channels")
    if np.any(np.diff(elev) <= 0):
        problems.append("elevation_deg must be strictly increasing (channel 0 lowest)")
    low, high = p.vertical_fov_deg
    if len(elev) and not (low <= elev.min() and elev.max() <= high):
        problems.append(f"elevations [{elev.min()}, {elev.max()}] fall outside vertical_fov_deg")
    for key in (
        "wavelength_nm",
        "beam_divergence_mrad",
        "max_range_m",
        "range_accuracy_m",
        "pulse_width_ns",
    ):
        if not getattr(p, key) > 0:
            problems.append(f"{key} must be > 0")
    if not 0 <= p.min_range_m < p.max_range_m:
        problems.append("need 0 <= min_range_m < max_range_m")
    if not p.min_range_m <= p.overlap_full_m < p.max_range_m:
        problems.append("need min_range_m <= overlap_full_m < max_range_m")
    if p.range_image_width < 4 or p.range_image_width % 4:
        problems.append("range_image_width must be a positive multiple of 4")
    enc = p.intensity
    if enc.kind not in ("unit", "byte") or not (0 < enc.step <= enc.max_value):
        problems.append("intensity needs kind unit|byte and 0 < step <= max_value")
    if not enc.reflectivity_full_scale > 0:
        problems.append("intensity.reflectivity_full_scale must be > 0")
    if p.sweep_period_s is not None and not 0 < p.sweep_period_s < 10:
        problems.append("sweep_period_s must lie in (0, 10) s")
    det = p.detection
    if not (det.reflectivity > 0 and det.range_m > 0 and det.spread_ln > 0):
        problems.append("detection needs reflectivity, range_m and spread_ln > 0")
    if problems:
        raise SensorProfileError(f"{path}: " + "; ".join(problems) + ".")
