"""The physical knobs of the snow model that `lads.calibration.wads` fits to real falling
snow (that module's docstring gives their physics), their bounds, the fitted values, and the
coordinates the optimiser moves them in."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import numpy.typing as npt

from lads.physics.particles import ParticleParams
from lads.physics.weather import SNOW_DEFAULTS, with_overrides
from lads.sensors.profile import DetectionLimit, SensorProfile, load_profile

# The sensor profile of the WADS recordings.
SENSOR = "wads64"

# Physical bounds of the fitted knobs.
BOUNDS = {
    "particle_reflectivity": (0.005, 2.0),
    "beam_divergence_mrad": (0.5, 10.0),
    "min_range_m": (0.0, 5.0),
    "overlap_extra_m": (0.0, 6.0),  # R2 - R1
    "detection_threshold": (1e-7, 1e-4),
}


@dataclass(frozen=True, slots=True)
class SnowKnobs:
    """The fitted physical knobs (module docstring).

    detection_threshold: the sensor's detection limit P_lim (reflectivity / m^2) the fit
    assumes for WADS' unknown sensor, or None for the profile's (`SensorProfile.detection`).
    """

    particle_reflectivity: float
    beam_divergence_mrad: float
    min_range_m: float
    overlap_full_m: float
    detection_threshold: float | None

    def params(self, base: ParticleParams = SNOW_DEFAULTS) -> ParticleParams:
        """The flake optics; detection stays the sensor's rule (`sensor` gives the limit)."""
        optics = {k: v for k, v in asdict(self).items() if k != "detection_threshold"}
        return with_overrides(base, **optics, detection_threshold="sensor")

    def sensor(self, profile: SensorProfile | str = SENSOR) -> SensorProfile:
        """`profile` with its detection limit replaced by the fitted one (if any)."""
        base = load_profile(profile) if isinstance(profile, str) else profile
        if self.detection_threshold is None:
            return base
        reference = base.detection.reflectivity
        limit = DetectionLimit(
            reflectivity=reference,
            range_m=math.sqrt(reference / self.detection_threshold),
            spread_ln=base.detection.spread_ln,
        )
        return replace(base, detection=limit)


# Result of `benchmarks.wads_snow` (dual-return mode, the WADS sensor's detection limit
# fitted with the flake optics on the fit frames at `wads.ASSUMED_RATE_MM_H`), rounded. The
# optics are SNOW_DEFAULTS' and the limit is wads64.yaml's `detection`.
FITTED_SNOW_KNOBS = SnowKnobs(
    particle_reflectivity=0.00855,
    beam_divergence_mrad=1.56,
    min_range_m=3.25,
    overlap_full_m=7.29,
    detection_threshold=8.69e-6,
)


def knobs_from_vector(x: npt.NDArray[np.float64], fit_threshold: bool) -> SnowKnobs:
    """The knobs at optimiser coordinates `x` (log10 rho_p, log10 theta, R1, R2 - R1,
    log10 P_lim), clipped to BOUNDS; P_lim None unless `fit_threshold`."""
    lo_hi = BOUNDS
    rho = float(np.clip(10 ** x[0], *lo_hi["particle_reflectivity"]))
    theta = float(np.clip(10 ** x[1], *lo_hi["beam_divergence_mrad"]))
    r1 = float(np.clip(x[2], *lo_hi["min_range_m"]))
    r2 = r1 + float(np.clip(x[3], *lo_hi["overlap_extra_m"]))
    p_min = float(np.clip(10 ** x[4], *lo_hi["detection_threshold"])) if fit_threshold else None
    return SnowKnobs(rho, theta, round(r1, 4), round(r2, 4), p_min)


def knob_vector(k: SnowKnobs) -> npt.NDArray[np.float64]:
    """(5,) float64 optimiser coordinates of `k` (`knobs_from_vector`'s inverse within
    BOUNDS; P_lim 1e-6 when the knobs leave it to the sensor)."""
    p = k.detection_threshold if k.detection_threshold is not None else 1e-6
    return np.array(
        [
            math.log10(k.particle_reflectivity),
            math.log10(k.beam_divergence_mrad),
            k.min_range_m,
            k.overlap_full_m - k.min_range_m,
            math.log10(p),
        ]
    )
