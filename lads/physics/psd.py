"""Particle size distributions of rain and snow: exponential N(D) = N0 exp(-Lambda D).

Diameters D in mm, N(D) in m^-3 mm^-1, rates in mm/h (water-equivalent for snow).
Sources: Marshall & Palmer (1948); Gunn & Marshall (1958); Sekhon & Srivastava (1970),
J. Atmos. Sci. 27(2), 299-307 (N0 = 2.50e3 R^-0.94 mm^-1 m^-3, Lambda = 22.9 R^-0.45 cm^-1,
D the melted diameter). LISA and its forks use twice the snow intercepts (docs/physics.md §1);
`n0_scale=2` reproduces them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lads.errors import ConfigError

# Fresh snowflakes are ~10x less dense than water; a flake of the same mass as a melted
# drop of diameter D is (rho_w / rho_s)^(1/3) times wider. Optics sees the flake.
SNOW_DENSITY_G_CM3 = 0.1


@dataclass(frozen=True, slots=True)
class ExponentialPSD:
    """N(D) = n0 * exp(-slope * D) for D >= min_diameter_mm (optical diameter).

    Attributes:
        n0_per_m3_mm: intercept N0 in m^-3 mm^-1.
        slope_per_mm: slope Lambda in mm^-1.
        min_diameter_mm: smallest particle counted, mm (LISA: 0.05 mm).
    """

    n0_per_m3_mm: float
    slope_per_mm: float
    min_diameter_mm: float = 0.05

    @property
    def number_per_m3(self) -> float:
        """Particles per m^3 with D >= min_diameter_mm: N0 exp(-Lambda D_min) / Lambda."""
        return (
            self.n0_per_m3_mm
            * math.exp(-self.slope_per_mm * self.min_diameter_mm)
            / (self.slope_per_mm)
        )

    def scaled_diameter(self, ratio: float) -> ExponentialPSD:
        """The same particles with every diameter multiplied by `ratio` (number conserved)."""
        return ExponentialPSD(
            self.n0_per_m3_mm / ratio, self.slope_per_mm / ratio, self.min_diameter_mm
        )


def _check_rate(rate_mm_h: float) -> None:
    if not (math.isfinite(rate_mm_h) and rate_mm_h > 0):
        raise ConfigError(
            f"precipitation rate {rate_mm_h!r} mm/h: expected a finite rate > 0 "
            "(rate 0 means clear air and is handled before any distribution is built)."
        )


def marshall_palmer(
    rate_mm_h: float, *, n0_scale: float = 1.0, min_diameter_mm: float = 0.05
) -> ExponentialPSD:
    """Rain: N0 = 8000 m^-3 mm^-1, Lambda = 4.1 R^-0.21 mm^-1 (Marshall & Palmer 1948)."""
    _check_rate(rate_mm_h)
    return ExponentialPSD(n0_scale * 8000.0, 4.1 * rate_mm_h**-0.21, min_diameter_mm)


def gunn_marshall(
    rate_mm_h: float, *, n0_scale: float = 1.0, min_diameter_mm: float = 0.05
) -> ExponentialPSD:
    """Snow, melted diameters: N0 = 3.8e3 R^-0.87, Lambda = 2.55 R^-0.48 mm^-1 (1958)."""
    _check_rate(rate_mm_h)
    return ExponentialPSD(
        n0_scale * 3.8e3 * rate_mm_h**-0.87, 2.55 * rate_mm_h**-0.48, min_diameter_mm
    )


def sekhon_srivastava(
    rate_mm_h: float, *, n0_scale: float = 1.0, min_diameter_mm: float = 0.05
) -> ExponentialPSD:
    """Snow, melted diameters: N0 = 2.5e3 R^-0.94, Lambda = 2.29 R^-0.45 mm^-1 (1970)."""
    _check_rate(rate_mm_h)
    return ExponentialPSD(
        n0_scale * 2.5e3 * rate_mm_h**-0.94, 2.29 * rate_mm_h**-0.45, min_diameter_mm
    )


def flake_diameter_ratio(snow_density_g_cm3: float = SNOW_DENSITY_G_CM3) -> float:
    """Optical / melted diameter of an equal-mass sphere: (rho_water / rho_snow)^(1/3)."""
    if not 0 < snow_density_g_cm3 <= 1:
        raise ConfigError(f"snow density {snow_density_g_cm3} g/cm^3: expected a value in (0, 1].")
    return (1.0 / snow_density_g_cm3) ** (1.0 / 3.0)


SIZE_DISTRIBUTIONS = {
    "marshall_palmer": marshall_palmer,
    "gunn_marshall": gunn_marshall,
    "sekhon_srivastava": sekhon_srivastava,
}
