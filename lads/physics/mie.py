"""Mie efficiencies of water and ice spheres and the extinction of a size distribution.

Efficiencies come from miepython (`efficiencies(m, d, lambda0)`, convention m = n - ik)
computed at run time, cached in memory and in the user cache (`lads.user_cache`); nothing
is shipped as a table. Above size parameter x = pi D / lambda = 3000 the Mie series is slow
(0.1 s per size at D = 5 mm) and the large-sphere asymptote Q_ext = 2 + 1.9924 x^(-2/3)
(van de Hulst 1957; Nussenzveig 1992, edge term of a non-absorbing sphere) is within
0.05 % of it.
"""

from __future__ import annotations

import functools
import importlib.metadata
import math

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.physics.psd import ExponentialPSD
from lads.user_cache import cached_array

# Complex refractive index n - ik near 905 nm. Water: Hale & Querry (1973), n = 1.328 (the
# value LISA uses). Ice: Warren & Brandt (2008), n = 1.3031 (LISA's ice value); k from
# memory (verify), irrelevant here since particles are far from absorbing at these sizes.
REFRACTIVE_INDEX = {
    "water": complex(1.328, -4.9e-7),
    "ice": complex(1.3031, -2.5e-7),
}
MIE_MAX_SIZE_PARAMETER = 3000.0
MIE_TABLE_SIZES = 320  # log-spaced diameters of the cached Q_ext table


def size_parameter(diameter_mm: npt.ArrayLike, wavelength_nm: float) -> npt.NDArray[np.float64]:
    """x = pi D / lambda for full diameters D (mm) at wavelength lambda (nm)."""
    return np.pi * np.asarray(diameter_mm, dtype=np.float64) * 1e6 / wavelength_nm


def _index(material: str) -> complex:
    if material not in REFRACTIVE_INDEX:
        raise ConfigError(
            f"particle material '{material}': expected one of {sorted(REFRACTIVE_INDEX)}."
        )
    return REFRACTIVE_INDEX[material]


def efficiencies(
    material: str, diameter_mm: npt.ArrayLike, wavelength_nm: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Extinction and backscatter efficiencies of spheres, float64 Mie (miepython).

    Args:
        material: "water" or "ice".
        diameter_mm: (K,) full diameters in mm; x must stay <= 3000 (D ~ 0.86 mm at 905 nm).
        wavelength_nm: vacuum wavelength in nm.

    Returns:
        (Q_ext, Q_back), each (K,). Q_back is in the radar convention (4 pi times the
        lidar value), so a sphere's Lambertian-equivalent reflectivity is Q_back / 4.
    """
    d = np.atleast_1d(np.asarray(diameter_mm, dtype=np.float64))
    if np.any(size_parameter(d, wavelength_nm) > MIE_MAX_SIZE_PARAMETER * 1.0001):
        raise ConfigError(
            f"Mie series requested for x > {MIE_MAX_SIZE_PARAMETER:g}; use "
            "extinction_efficiency(), which switches to the large-sphere asymptote."
        )
    import miepython  # on first use: it pulls in scipy.special, a tenth of a second at start

    qext, _qsca, qback, _g = miepython.efficiencies(_index(material), d, wavelength_nm * 1e-6)
    return np.asarray(qext, dtype=np.float64), np.asarray(qback, dtype=np.float64)


@functools.lru_cache(maxsize=8)
def _qext_table(material: str, wavelength_nm: float) -> tuple[np.ndarray, np.ndarray]:
    d_max = MIE_MAX_SIZE_PARAMETER * wavelength_nm * 1e-6 / np.pi
    d = np.geomspace(1e-4, d_max, MIE_TABLE_SIZES)
    # ~1.5 s of Mie series per table: kept on disk so each build worker does not redo it.
    key = (
        f"{_index(material)!r} {wavelength_nm!r} {d_max!r} {MIE_TABLE_SIZES} "
        f"miepython {importlib.metadata.version('miepython')}"
    )
    q = cached_array("mie-qext", key, lambda: efficiencies(material, d, wavelength_nm)[0])
    if q.shape != d.shape:
        q = efficiencies(material, d, wavelength_nm)[0]
    return np.log(d), q


def extinction_efficiency(
    material: str, diameter_mm: npt.ArrayLike, wavelength_nm: float
) -> npt.NDArray[np.float64]:
    """Q_ext(D) for any D >= 0.1 um: cached Mie table below x = 3000, asymptote above.

    Args/Returns: diameters (K,) in mm -> (K,) float64 efficiencies.
    """
    d = np.asarray(diameter_mm, dtype=np.float64)
    log_d, q = _qext_table(material, float(wavelength_nm))
    x = size_parameter(d, wavelength_nm)
    asymptote = 2.0 + 1.9924 * np.maximum(x, 1.0) ** (-2.0 / 3.0)
    inside = np.interp(np.log(np.maximum(d, 1e-4)), log_d, q)
    return np.where(x > MIE_MAX_SIZE_PARAMETER, asymptote, inside)


@functools.lru_cache(maxsize=256)
def extinction_per_m(psd: ExponentialPSD, material: str, wavelength_nm: float) -> float:
    """alpha = 1e-6 * integral N(D) Q_ext(D) (pi/4) D^2 dD over D >= D_min, in 1/m.

    The 1e-6 turns mm^2 into m^2. Integrated on a dense grid out to D_min + 40/Lambda
    (the tail beyond holds < e^-40 of the particles). With Q_ext = 2 and D_min = 0 this is
    the closed form pi N0 / Lambda^3 * 1e-6 (docs/physics.md §2).
    """
    lam = psd.slope_per_mm
    d = psd.min_diameter_mm + np.linspace(0.0, 40.0 / lam, 4001)
    integrand = (
        psd.n0_per_m3_mm
        * np.exp(-lam * d)
        * extinction_efficiency(material, d, wavelength_nm)
        * (math.pi / 4.0)
        * d**2
    )
    # The trapezoid rule, as scipy.integrate.trapezoid computes it (importing scipy.integrate
    # cost a quarter second of every build worker's start).
    return float(1e-6 * (np.diff(d) * (integrand[1:] + integrand[:-1]) / 2.0).sum())
