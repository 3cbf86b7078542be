"""Shared per-beam bookkeeping for every weather model: input checks, power units, output.

Power convention (LISA, Kilic et al. 2021; docs/physics.md §4 and §9): one input point is one
beam whose hard target has reflectivity rho (the stored intensity converted through the
profile's encoding; it already contains cos(theta)). Received power is normalised so that
a target at range r gives P0 = rho * T^2 / r^2 with two-way transmission T^2 = exp(-2 alpha r).
A return's output intensity is its received power times r^2 (intensities carry no 1/r^2),
encoded back into the dataset's units.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import InvalidPointsError
from lads.physics.detection import Detection, resolve_detection
from lads.physics.kernels import survivors
from lads.physics.result import Outcome, WeatherResult
from lads.sensors.profile import SensorProfile, load_profile

ZERO_RANGE_M = 1e-6


@dataclass(frozen=True, slots=True)
class Beams:
    """Validated input of one frame.

    Attributes:
        xyz: (N, 3) float32 input coordinates, m; possibly a strided view of the caller's
            array (never written to).
        intensity: (N,) float32 input intensities in the sensor encoding.
        range_m: (N,) float64 range, m.
        reflectivity: (N,) float64 target reflectivity (times cos theta), unitless; a stored
            0 counts as the encoding's detection floor (half a step), since it was detected.
        active: (N,) bool, beams the weather acts on; zero-range rows (range <= 1e-6 m,
            "no return" placeholders some datasets store) pass through unchanged.
        clear_power: (N,) clear-air received power rho / r^2 (inactive beams: +inf).
    """

    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    range_m: npt.NDArray[np.float64]
    reflectivity: npt.NDArray[np.float64]
    active: npt.NDArray[np.bool_]
    clear_power: npt.NDArray[np.float64]


def resolve_sensor(sensor: SensorProfile | str) -> SensorProfile:
    return sensor if isinstance(sensor, SensorProfile) else load_profile(sensor)


def prepare_beams(xyz: Any, intensity: Any, sensor: SensorProfile) -> Beams:
    """Validate a frame and derive ranges and reflectivities.

    Args:
        xyz: (N, 3) coordinates in m, any float dtype.
        intensity: (N,) intensities in `sensor.intensity`'s encoding.
        sensor: the profile the data was recorded with.

    Raises:
        InvalidPointsError: wrong shapes, or NaN/inf coordinates (with how many and where).
        IntensityEncodingError: intensities outside the encoding.
    """
    xyz = np.asarray(xyz)
    intensity = np.asarray(intensity)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InvalidPointsError(
            f"xyz has shape {xyz.shape}; expected (N, 3) metres. Slice the x, y, z columns "
            "out of the scan first (e.g. points[:, :3])."
        )
    if intensity.shape != (xyz.shape[0],):
        raise InvalidPointsError(
            f"intensity has shape {intensity.shape}; expected ({xyz.shape[0]},), one value per "
            "point of xyz."
        )
    # Columns, not rows: scans are often (N, 4) views, and row-wise reductions over a
    # strided view are several times slower. A NaN/inf coordinate makes r^2 non-finite.
    x, y, z = (xyz[:, k].astype(np.float64) for k in range(3))
    range_sq = x * x + y * y + z * z
    if not np.isfinite(range_sq).all():
        bad = ~np.isfinite(xyz).all(axis=1)
        first = np.flatnonzero(bad)[:5].tolist()
        raise InvalidPointsError(
            f"{int(bad.sum())} of {len(xyz)} points have NaN or infinite coordinates (first "
            f"indices {first}); remove or repair them before simulating weather."
        )
    sensor.intensity.validate(intensity, "intensity")
    # No contiguous copy: the compiled gather in `assemble` reads (N, 4) views directly.
    xyz32 = xyz.astype(np.float32, copy=False)
    range_m = np.sqrt(range_sq)
    rho = np.maximum(sensor.intensity.to_reflectivity(intensity), sensor.intensity.detection_floor)
    active = range_m > ZERO_RANGE_M
    with np.errstate(divide="ignore"):
        clear_power = rho / range_sq
    if not active.all():
        clear_power[~active] = np.inf
    return Beams(
        xyz=xyz32,
        intensity=intensity.astype(np.float32, copy=False),
        range_m=range_m,
        reflectivity=rho,
        active=active,
        clear_power=clear_power,
    )


def auto_threshold(beams: Beams) -> float:
    """Detection threshold calibrated to the frame: the weakest clear-air return.

    Every input point was detected in clear air, so the sensor's threshold lies at or below
    the smallest clear-air power in the frame; taking that bound guarantees that clear
    weather loses nothing (LISA's fixed threshold drops 4 % of a real clear KITTI scan,
    whose far returns often store remission 0; docs/physics.md §5.2).
    """
    power = beams.clear_power
    return float(power.min()) if power.size and np.isfinite(power).any() else 1.0


def assemble(
    beams: Beams,
    sensor: SensorProfile,
    *,
    outcome: npt.NDArray[np.uint8],
    range_m: npt.NDArray[np.float64],
    reflectivity: npt.NDArray[np.float64],
    extinction_per_m: float,
    detection_threshold: float,
) -> WeatherResult:
    """Build the result from per-beam decisions.

    Args:
        beams: the prepared input (N beams).
        outcome: (N,) uint8 Outcome per beam, LOST included.
        range_m: (N,) new range of each beam's return, m (ignored for KEPT and LOST).
        reflectivity: (N,) new intensity of each return as reflectivity (ignored for KEPT
            and LOST).
    """
    none = np.full(outcome.size, Outcome.LOST, dtype=np.uint8)  # no second returns
    source, out, xyz, intensity = survivors(
        beams.xyz,
        beams.range_m,
        beams.intensity,
        *sensor.intensity.compiled,
        outcome,
        range_m,
        reflectivity,
        none,
        range_m,
        reflectivity,
    )
    return WeatherResult(
        xyz=xyz,
        intensity=intensity,
        source_index=source,
        outcome=out,
        lost_index=np.flatnonzero(outcome == Outcome.LOST).astype(np.int64),
        extinction_per_m=float(extinction_per_m),
        detection_threshold=float(detection_threshold),
    )


def assemble_dual(
    beams: Beams,
    sensor: SensorProfile,
    *,
    first: tuple[npt.NDArray[np.uint8], npt.NDArray[np.float64], npt.NDArray[np.float64]],
    second: tuple[npt.NDArray[np.uint8], npt.NDArray[np.float64], npt.NDArray[np.float64]],
    extinction_per_m: float,
    detection_threshold: float,
) -> WeatherResult:
    """`assemble` for a dual-return frame: per beam its first return, then its second.

    Args:
        first, second: (outcome, range_m, reflectivity), each (N,), as `assemble` takes
            them; a beam whose second outcome is LOST gives one output point (or none if
            its first is LOST too). Lost beams are those whose first return is LOST.
    """
    codes1, range1_m, refl1 = first
    codes2, range2_m, refl2 = second
    source, outcome, xyz, intensity = survivors(
        beams.xyz,
        beams.range_m,
        beams.intensity,
        *sensor.intensity.compiled,
        codes1,
        range1_m,
        refl1,
        codes2,
        range2_m,
        refl2,
    )
    return WeatherResult(
        xyz=xyz,
        intensity=intensity,
        source_index=source,
        outcome=outcome,
        lost_index=np.flatnonzero(first[0] == Outcome.LOST).astype(np.int64),
        extinction_per_m=float(extinction_per_m),
        detection_threshold=float(detection_threshold),
    )


def fixed_threshold_in_clear_air(
    beams: Beams, sensor: SensorProfile, rule: Detection
) -> WeatherResult | None:
    """Clear air (rate 0, visibility inf) under a fixed detection threshold (LISA's model):
    the returns weaker than it are LOST, as at any rate, so that a weather's loss tends to
    this one as its rate tends to 0; the rest KEPT with their input bytes. None under the
    sensor's limit or the frame's threshold, which every clear-air return meets: the caller
    then returns the frame unchanged."""
    if rule.setting != "fixed":
        return None
    lost = beams.active & (beams.clear_power < rule.threshold)
    if not lost.any():
        return None
    n = beams.range_m.size
    return assemble(
        beams,
        sensor,
        outcome=np.where(lost, Outcome.LOST, Outcome.KEPT).astype(np.uint8),
        range_m=np.zeros(n),
        reflectivity=np.zeros(n),
        extinction_per_m=0.0,
        detection_threshold=rule.threshold,
    )


def unchanged(beams: Beams, sensor: SensorProfile) -> WeatherResult:
    """Clear air: every point KEPT with its input bytes."""
    n = beams.range_m.size
    return WeatherResult(
        xyz=np.array(beams.xyz, dtype=np.float32, order="C"),
        intensity=beams.intensity.copy(),
        source_index=np.arange(n, dtype=np.int64),
        outcome=np.full(n, Outcome.KEPT, dtype=np.uint8),
        lost_index=np.zeros(0, dtype=np.int64),
        extinction_per_m=0.0,
        detection_threshold=auto_threshold(beams) if n else 0.0,
    )


def dimmed(
    beams: Beams,
    profile: SensorProfile,
    ratio: npt.NDArray[np.float64],
    active: npt.NDArray[np.bool_],
    detection: str | float,
    rng: np.random.Generator,
) -> WeatherResult:
    """Returns whose power and intensity a surface change scales by `ratio` (a water film, a
    darker paint): each `active` return is still detected or lost by the detection rule,
    conditioned on its clear-air detection; every other point is KEPT.

    Args:
        ratio: (N,) power factor per beam, 1 where nothing changes.
        active: (N,) the beams the change acts on.
        detection: the rule (`lads.physics.detection.resolve_detection`).
    """
    rule = resolve_detection(
        detection, profile.detection.power, profile.detection.spread_ln, auto_threshold(beams)
    )
    detected, _ = rule.targets_detected(beams.clear_power, np.log(ratio), active, rng)
    outcome = np.full(beams.range_m.size, Outcome.KEPT, dtype=np.uint8)
    outcome[active] = Outcome.LOST
    outcome[active & detected] = Outcome.ATTENUATED
    reflectivity = profile.intensity.to_reflectivity(beams.intensity) * ratio
    return assemble(
        beams,
        profile,
        outcome=outcome,
        range_m=beams.range_m,
        reflectivity=reflectivity,
        extinction_per_m=0.0,
        detection_threshold=rule.threshold,
    )
