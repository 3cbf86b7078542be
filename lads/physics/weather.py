"""Public weather API: rain, snow and fog on one frame, usable inside a data loader.

    result = rain(xyz, intensity, rate_mm_h=25.0, sensor="hdl64e", rng=rng)
    labels_out = labels[result.source_index]

Every function validates its input (`lads.physics.beams.prepare_beams`), draws all its
randomness from `rng` (same generator state, same bytes) and returns a `WeatherResult`.
Rate 0 (or visibility inf) returns the input unchanged.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from lads.physics.beams import prepare_beams, resolve_sensor
from lads.physics.fog import FogParams, simulate_fog
from lads.physics.particles import ParticleParams, simulate_particles
from lads.physics.psd import flake_diameter_ratio
from lads.physics.result import WeatherResult
from lads.sensors.profile import SensorProfile

# Rain: Marshall-Palmer drops, water Mie extinction, Fresnel backscatter (LISA). No real
# rain recording is available to calibrate particle_reflectivity; the Fresnel value is the
# conservative end of the physical range (Mie Q_back/4 would be 20-90x brighter).
RAIN_DEFAULTS = ParticleParams(
    size_distribution="marshall_palmer",
    material="water",
    particle_reflectivity=0.0199,
)

# Snow: Gunn-Marshall melted diameters widened to flakes of 0.1 g/cm^3, ice Mie extinction.
# particle_reflectivity, beam divergence and minimum range are fitted to real falling snow
# (WADS) by lads.calibration.wads; see benchmarks/results/wads_snow.json.
SNOW_DEFAULTS = ParticleParams(
    size_distribution="gunn_marshall",
    material="ice",
    particle_reflectivity=0.0173,
    diameter_ratio=flake_diameter_ratio(),
)


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
        mode: "strongest" or "last" return.
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

    Arguments as `rain`, with visibility_m > 0 (inf = clear air) instead of a rate.
    """
    profile = resolve_sensor(sensor)
    beams = prepare_beams(xyz, intensity, profile)
    return simulate_fog(
        beams, profile, visibility_m=visibility_m, rng=rng, mode=mode, params=params
    )


def with_overrides(params: ParticleParams, **changes: Any) -> ParticleParams:
    """A copy of `params` with some fields changed (validated again)."""
    return replace(params, **changes)
