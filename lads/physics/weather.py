"""Public weather API: rain, snow and fog on one frame, usable inside a data loader.

    result = rain(xyz, intensity, rate_mm_h=25.0, sensor="hdl64e", rng=rng)
    labels_out = labels[result.source_index]

Every function validates its input (`lads.physics.beams.prepare_beams`), draws all its
randomness from `rng` (same generator state, same bytes) and returns a `WeatherResult`.
Rate 0 (or visibility inf) returns the input unchanged, except under a fixed detection
threshold (LISA's), which drops the clear-air returns weaker than it there as at any rate.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from lads.errors import ConfigError
from lads.physics.beams import prepare_beams, resolve_sensor
from lads.physics.fog import FogParams, simulate_fog
from lads.physics.particles import ParticleParams, simulate_particles
from lads.physics.psd import flake_diameter_ratio
from lads.physics.result import WeatherResult
from lads.sensors.profile import SensorProfile

# Where faint returns (drops, flakes, fog) become visible. Real falling snow (WADS: none
# nearer than ~3 m though hard targets are seen from 0.3 m) and real fog (RADIATE HDL-32E:
# no fog echo at 1-3 m) both show that the receiver barely sees faint returns within a few
# metres: the transmitter/receiver overlap of a bistatic sensor, modelled as a linear ramp
# from FAINT_ONSET_M to FAINT_FULL_M (fitted on WADS by lads.calibration.wads, see
# benchmarks/results/wads_snow.json). Bright hard targets still pass at short range. The same
# sensor-side onset serves rain, snow and fog, since no rain recording exists to fit it.
FAINT_ONSET_M = 3.25
FAINT_FULL_M = 7.29

# Rain: Marshall-Palmer drops, water Mie extinction, Fresnel backscatter (LISA). No real
# rain recording is available to calibrate particle_reflectivity; the Fresnel value is the
# conservative end of the physical range (Mie Q_back/4 would be 20-90x brighter).
RAIN_DEFAULTS = ParticleParams(
    size_distribution="marshall_palmer",
    material="water",
    particle_reflectivity=0.0199,
    min_range_m=FAINT_ONSET_M,
    overlap_full_m=FAINT_FULL_M,
)

# Snow: Gunn-Marshall melted diameters widened to flakes of 0.1 g/cm^3, ice Mie extinction,
# and the knobs fitted to real falling snow (WADS seq 36, a dual-return recording, fitted in
# the dual-return mode together with the WADS sensor's detection limit at an assumed
# 2.5 mm/h; `python -m benchmarks.wads_snow`, held-out frames reported there): effective
# flake reflectivity 0.00855 (below ice Fresnel 0.0173: real flakes read ~0 intensity, and
# only rho_p / P_lim sets the flake count), divergence 1.56 mrad (trades off against the
# reflectivity), onset 3.25 -> 7.29 m. These are effective values of a single-scattering
# model at an assumed rate; the reflectivity is only meaningful together with that rate.
SNOW_DEFAULTS = ParticleParams(
    size_distribution="gunn_marshall",
    material="ice",
    particle_reflectivity=0.00855,
    diameter_ratio=flake_diameter_ratio(),
    beam_divergence_mrad=1.56,
    min_range_m=FAINT_ONSET_M,
    overlap_full_m=FAINT_FULL_M,
)

# Fog: Mie lidar ratio of advection-fog droplets (~17 sr) and the same faint-return onset.
FOG_DEFAULTS = FogParams(overlap_start_m=FAINT_ONSET_M, overlap_full_m=FAINT_FULL_M)


def with_overrides(params: ParticleParams, **changes: Any) -> ParticleParams:
    """A copy of `params` with some fields changed (validated again)."""
    return replace(params, **changes)


# LISA's published model (Kilic et al. 2021, paper code / pylisa; docs/physics.md §4), an
# explicit setting to compare with: Fresnel particle reflectivity, 3 mrad, a 1.5 m blind
# zone with no overlap ramp, range accuracy 0.09 m and the fixed threshold P_min = 0.9 /
# 200^2 (a 90 % target just detectable at 200 m), which also drops weak clear-air returns.
LISA_RAIN = ParticleParams(
    size_distribution="marshall_palmer",
    material="water",
    particle_reflectivity=0.01985,
    beam_divergence_mrad=3.0,
    min_range_m=1.5,
    range_accuracy_m=0.09,
    detection_threshold=0.9 / 200.0**2,
)
# Snow: the same beam and threshold, Gunn-Marshall with twice the primary intercept, melted
# diameter taken as optical, Fresnel reflectivity of ice.
LISA_SNOW = with_overrides(
    LISA_RAIN,
    size_distribution="gunn_marshall",
    material="ice",
    particle_reflectivity=0.01732,
    n0_scale=2.0,
    diameter_ratio=1.0,
)
# The physics settings a weather stage can run with: lads' own (fitted to real snow, the
# sensor's detection limit) or LISA's published ones. Fog has no LISA setting here (LISA's
# fog is another model, docs/physics.md §4).
SETTINGS: dict[str, dict[str, ParticleParams | FogParams]] = {
    "lads": {"rain": RAIN_DEFAULTS, "snow": SNOW_DEFAULTS, "fog": FOG_DEFAULTS},
    "lisa": {"rain": LISA_RAIN, "snow": LISA_SNOW},
}


def settings_for(weather: str, settings: str) -> ParticleParams | FogParams:
    """The physical knobs of `weather` under the named settings.

    Raises:
        ConfigError: unknown settings, or a weather they do not cover.
    """
    if settings not in SETTINGS:
        raise ConfigError(f"weather settings {settings!r}: expected one of {sorted(SETTINGS)}.")
    if weather not in SETTINGS[settings]:
        raise ConfigError(
            f"weather settings '{settings}' have no {weather} model; use 'lads' for {weather}."
        )
    return SETTINGS[settings][weather]


def rain(
    xyz: Any,
    intensity: Any,
    *,
    rate_mm_h: float,
    sensor: SensorProfile | str,
    rng: np.random.Generator,
    mode: str = "strongest",
    params: ParticleParams | None = None,
) -> WeatherResult:
    """Rain at `rate_mm_h` (mm/h) on one frame.

    Args:
        xyz: (N, 3) point coordinates in m, sensor frame.
        intensity: (N,) intensities in the sensor profile's encoding.
        rate_mm_h: rain rate in mm/h, >= 0.
        sensor: SensorProfile or shipped profile name ("hdl64e", "hdl32e", "wads64").
        rng: numpy Generator owned by this frame.
        mode: "strongest" or "last" return, or "dual" (the strongest and, where it differs,
            the last: a beam may then give two output points, adjacent in source_index).
        params: physical knobs; defaults to RAIN_DEFAULTS.

    Returns:
        WeatherResult with per output point xyz, intensity, source_index and outcome.

    Raises:
        InvalidPointsError, IntensityEncodingError: bad input arrays.
        ConfigError: negative or NaN rate, unknown mode, invalid params.
    """
    profile = resolve_sensor(sensor)
    beams = prepare_beams(xyz, intensity, profile)
    return simulate_particles(
        beams, profile, rate_mm_h=rate_mm_h, rng=rng, mode=mode, params=params or RAIN_DEFAULTS
    )


def snow(
    xyz: Any,
    intensity: Any,
    *,
    rate_mm_h: float,
    sensor: SensorProfile | str,
    rng: np.random.Generator,
    mode: str = "strongest",
    params: ParticleParams | None = None,
) -> WeatherResult:
    """Snow at water-equivalent `rate_mm_h` (mm/h) on one frame; arguments as `rain`.

    params defaults to SNOW_DEFAULTS (fitted to WADS real snow).
    """
    profile = resolve_sensor(sensor)
    beams = prepare_beams(xyz, intensity, profile)
    return simulate_particles(
        beams, profile, rate_mm_h=rate_mm_h, rng=rng, mode=mode, params=params or SNOW_DEFAULTS
    )


def fog(
    xyz: Any,
    intensity: Any,
    *,
    visibility_m: float,
    sensor: SensorProfile | str,
    rng: np.random.Generator,
    mode: str = "strongest",
    params: FogParams | None = None,
) -> WeatherResult:
    """Fog of meteorological optical range `visibility_m` (m) on one frame.

    Arguments as `rain`, with visibility_m > 0 (inf = clear air) instead of a rate;
    params defaults to FOG_DEFAULTS.
    """
    profile = resolve_sensor(sensor)
    beams = prepare_beams(xyz, intensity, profile)
    return simulate_fog(
        beams,
        profile,
        visibility_m=visibility_m,
        rng=rng,
        mode=mode,
        params=FOG_DEFAULTS if params is None else params,
    )
