"""Fog optics: extinction from visibility (Koschmieder) and the lidar ratio of a droplet size
distribution (Mie theory through miepython, or Hahner et al.'s constant), which give the
backscatter the fog echo scales with (docs/physics.md §7)."""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np

from lads.errors import ConfigError

if TYPE_CHECKING:
    from lads.physics.fog import FogParams

KOSCHMIEDER_LN20 = math.log(20.0)
MIE_SIZES = 1500  # Q_back ripples with size; ~1000 sizes converge S to +-1 % (measured)


def extinction_from_visibility(visibility_m: float) -> float:
    """Extinction alpha = ln(20) / MOR in 1/m (Koschmieder, 5 % contrast); MOR = inf -> 0.

    Raises:
        ConfigError: visibility_m is NaN or <= 0.
    """
    v = float(visibility_m)
    if math.isnan(v) or v <= 0:
        raise ConfigError(
            f"visibility_m = {visibility_m!r}; expected a meteorological optical range > 0 m "
            "(e.g. 50 for dense fog, 1000 for mist; inf for clear air)."
        )
    return 0.0 if math.isinf(v) else KOSCHMIEDER_LN20 / v


def lidar_ratio_sr(params: FogParams) -> float:
    """Lidar ratio S = alpha / beta_pi in sr used by `params.backscatter_model`."""
    if params.backscatter_model == "hahner":
        return KOSCHMIEDER_LN20 / params.hahner_backscatter_factor
    return _mie_lidar_ratio_sr(
        params.droplet_modal_radius_um,
        params.droplet_shape_a,
        params.droplet_shape_g,
        params.refractive_index,
        params.wavelength_nm,
    )


def backscatter_from_visibility(visibility_m: float, params: FogParams) -> float:
    """Lidar backscatter coefficient beta_pi in 1/(m sr) for a visibility (MOR) in m.

    "mie": alpha / S with S from `lidar_ratio_sr`; "hahner": 0.046 / MOR (Hahner et al. 2021).

    Raises:
        ConfigError: visibility_m is NaN or <= 0.
    """
    alpha = extinction_from_visibility(visibility_m)
    return alpha / lidar_ratio_sr(params)


@functools.lru_cache(maxsize=8)
def _mie_lidar_ratio_sr(
    modal_radius_um: float, shape_a: float, shape_g: float, index: float, wavelength_nm: float
) -> float:
    # miepython pulls in numba; import on first use so `import lads` stays light.
    import miepython
    from scipy.integrate import trapezoid

    # The tail beyond 6 r_c carries < 0.2 % of the cross-section for a = 3, g = 1.
    radius_um = np.linspace(0.05, 6.0 * modal_radius_um, MIE_SIZES)
    number = radius_um**shape_a * np.exp(
        -(shape_a / shape_g) * (radius_um / modal_radius_um) ** shape_g
    )
    area = number * np.pi * radius_um**2
    qext, _, qback, _ = miepython.efficiencies(index, 2.0 * radius_um, wavelength_nm * 1e-3)
    # miepython's qback is the radar convention, 4 pi times the lidar (per sr) value.
    return float(
        trapezoid(area * qext, radius_um) / (trapezoid(area * qback, radius_um) / (4 * np.pi))
    )
