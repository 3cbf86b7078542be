"""Wet ground: a water film on road-like surfaces darkens them and drops weak returns.

Model (docs/physics.md §8.2; the principle of Lekner and Dorf 1988, "Why some things are
darker when wet", applied to a monostatic LiDAR). A beam meets a horizontal ground point at
incidence theta (cos theta = -z / r for a sensor above locally flat ground). Where the film
covers the surface:
- the air-water interface reflects R(theta) of the beam away from the sensor (the specular
  term: a mirror sends it forward, never back to a monostatic receiver), so (1 - R) enters;
- the rough ground under the water scatters it diffusely; of the light scattered upwards a
  share R_i is reflected back down by the water surface (total internal reflection beyond
  the critical angle), where the ground absorbs 1 - A of it: a gain 1 / (1 - A R_i) on the
  escaping light;
- leaving the water the light passes the interface again, (1 - R), and its radiance spreads
  into a larger solid angle, 1 / n^2;
- the film absorbs exp(-2 alpha_w d / cos theta_t) on the way down and up.
So the backscatter of covered ground relative to dry ground is

    g_wet(theta) = (1 - R(theta))^2 / n^2 / (1 - A R_i) exp(-2 alpha_w d / cos theta_t),

and a film thinner than the surface's texture depth T covers only a share f = min(d / T, 1)
of it (the texture's peaks stay dry): g = 1 - f + f g_wet. A return's power and intensity are
multiplied by g; whether it is still detected follows the detection rule of the weather
(`lads.physics.detection`: conditioned on its clear-air detection), which gives the
incidence-dependent dropout: grazing, far, dark road goes first.

Not modelled: ghost points from the specular beam reflected by objects beyond, spray, and
puddles (a film thicker than the texture everywhere is one uniform layer here).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.physics.beams import dimmed, prepare_beams, resolve_sensor, unchanged
from lads.physics.materials import reflectance_for_labels, wet_surface_for_labels
from lads.physics.result import WeatherResult
from lads.sensors.profile import SensorProfile

# Water at 905 nm: refractive index (as the fog droplets, docs/physics.md §2) and absorption
# coefficient 4 pi k / lambda with k ~ 4.9e-7 (Hale and Querry 1973, Applied Optics 12, 555;
# from memory, verify): ~6.8 1/m, i.e. a 1 mm film absorbs ~1 % per pass.
WATER_REFRACTIVE_INDEX = 1.328
WATER_ABSORPTION_PER_M = 6.8
# Below this cos(theta) a ground point is taken as seen at grazing incidence (89.4 deg).
MIN_COS_INCIDENCE = 0.01


@dataclass(frozen=True, slots=True)
class WetGroundParams:
    """Physical knobs of the water film.

    Attributes:
        water_film_mm: film thickness d above the texture's base, mm (0 = dry).
        refractive_index: n of water at the laser wavelength.
        absorption_per_m: alpha_w of water at the laser wavelength, 1/m.
    """

    water_film_mm: float
    refractive_index: float = WATER_REFRACTIVE_INDEX
    absorption_per_m: float = WATER_ABSORPTION_PER_M

    def __post_init__(self) -> None:
        if not (math.isfinite(self.water_film_mm) and self.water_film_mm >= 0):
            raise ConfigError(
                f"water_film_mm = {self.water_film_mm!r}; expected a finite thickness >= 0 mm."
            )
        if not (self.refractive_index > 1 and self.absorption_per_m >= 0):
            raise ConfigError("WetGroundParams: need refractive_index > 1, absorption_per_m >= 0.")


def fresnel_unpolarised(cos_i: npt.NDArray[np.float64], n: float) -> npt.NDArray[np.float64]:
    """Fresnel reflectance (mean of s and p) from air into a medium of index n; (N,) in [0, 1]."""
    cos_i = np.clip(cos_i, 0.0, 1.0)
    sin_t = np.sqrt(1.0 - cos_i**2) / n
    cos_t = np.sqrt(1.0 - sin_t**2)
    r_s = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    r_p = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (r_s**2 + r_p**2)


@functools.lru_cache(maxsize=8)
def internal_diffuse_reflectance(n: float) -> float:
    """R_i: share of diffuse (Lambertian) light from inside a medium of index n that its
    surface reflects back, total internal reflection included.

    Light that escapes is the external-side view: by reciprocity the transmitted share equals
    (1 - R_e) / n^2 with R_e the cosine-weighted mean external reflectance.
    """
    # Gauss-Legendre on [0, pi/2]; the integrand is smooth there, 64 nodes reach 1e-12.
    nodes, weights = np.polynomial.legendre.leggauss(64)
    theta = 0.25 * math.pi * (nodes + 1.0)
    integrand = fresnel_unpolarised(np.cos(theta), n) * 2.0 * np.sin(theta) * np.cos(theta)
    mean_external = 0.25 * math.pi * float(np.sum(weights * integrand))
    return 1.0 - (1.0 - mean_external) / n**2


def wet_ratio(
    cos_i: npt.NDArray[np.float64],
    albedo: npt.NDArray[np.float64],
    texture_depth_mm: npt.NDArray[np.float64],
    params: WetGroundParams,
) -> npt.NDArray[np.float64]:
    """g: backscatter of wet over dry ground per point (module docstring); (N,) in (0, 1].

    Args:
        cos_i: (N,) cosine of the incidence angle.
        albedo: (N,) diffuse reflectance A of the dry ground material.
        texture_depth_mm: (N,) mean texture depth T, mm (> 0).
    """
    n = params.refractive_index
    cos_i = np.clip(cos_i, MIN_COS_INCIDENCE, 1.0)
    transmit = 1.0 - fresnel_unpolarised(cos_i, n)
    cos_t = np.sqrt(1.0 - (1.0 - cos_i**2) / n**2)
    absorbed = np.exp(-2.0 * params.absorption_per_m * 1e-3 * params.water_film_mm / cos_t)
    trapped = 1.0 - np.clip(albedo, 0.0, 1.0) * internal_diffuse_reflectance(n)
    covered = transmit**2 / n**2 / trapped * absorbed
    share = np.minimum(params.water_film_mm / texture_depth_mm, 1.0)
    return 1.0 - share + share * covered


def wet_ground(
    xyz: Any,
    intensity: Any,
    labels: Any,
    label_set: str,
    *,
    sensor: SensorProfile | str,
    rng: np.random.Generator,
    params: WetGroundParams,
    detection: str | float = "sensor",
) -> WeatherResult:
    """A water film on the frame's road-like points (labels marked `ground` in materials.yaml).

    Args:
        xyz: (N, 3) point coordinates in m, sensor frame (z up).
        intensity: (N,) intensities in the sensor profile's encoding.
        labels: (N,) the frame's labels; label_set: their materials.yaml label set.
        sensor: SensorProfile or shipped profile name.
        rng: the frame's generator (detection draws only).
        params: the film.
        detection: the detection rule (`lads.physics.detection.resolve_detection`).

    Returns:
        WeatherResult: wet ground ATTENUATED (intensity times g) or LOST, every other point KEPT
        with its input bytes.
    """
    profile = resolve_sensor(sensor)
    beams = prepare_beams(xyz, intensity, profile)
    wettable, depth_mm = wet_surface_for_labels(labels, label_set)
    wet = beams.active & wettable
    if params.water_film_mm == 0 or not wet.any():
        return unchanged(beams, profile)
    albedo = reflectance_for_labels(labels, label_set).astype(np.float64)
    cos_i = np.zeros(beams.range_m.size)
    cos_i[wet] = -beams.xyz[wet, 2].astype(np.float64) / beams.range_m[wet]
    ratio = np.ones(beams.range_m.size)
    ratio[wet] = wet_ratio(cos_i[wet], albedo[wet], depth_mm[wet], params)
    return dimmed(beams, profile, ratio, wet, detection, rng)
