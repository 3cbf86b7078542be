"""A sensor's detection limit measured from its own clear-weather frames.

A sensor that reports calibrated reflectivity (Velodyne's HDL-32E in nuScenes: 0-100 for
0-100 % diffuse) shows its detection limit directly: a target of reflectivity rho at range r
returns P = rho / r^2, and the sensor reports it with probability
    p(P) = Phi((ln P - ln P_lim) / s)          (docs/physics.md §9.7),
so the weak end of the reported reflectivities rises as r^2 with range. Fit (P_lim, s) by
maximum likelihood of each return's reflectivity level given its range:
    P(level k | range bin b) = w_k p(rho_k / r_b^2) / sum_j w_j p(rho_j / r_b^2),
with the scene's reflectivity mix w_k free (one weight per level, shared by all ranges) and
r_b the mean range of the bin's returns. Conditioning on range removes how many targets
each range holds; the limit is identified because the same reflectivity is seen near and
lost far. Assumes the reflectivity mix does not change with range (the scene's far targets
are as dark as its near ones): where far targets are brighter, P_lim comes out low.

Only diffuse levels (rho <= 1) enter; retro-reflectors are always detected and carry no
information about the limit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize
from scipy.special import log_ndtr

from lads.errors import ConfigError
from lads.sensors.profile import SensorProfile

# Range window of the fit, m: nearer returns sit far above any limit (no information) and
# include the vehicle body; the bins are narrow enough that r^2 changes < 25 % within one.
FIT_MIN_RANGE_M = 10.0
RANGE_BIN_M = 1.0
# Gauge and empty levels: a weak pull of the level weights toward 0 (the likelihood alone
# is unchanged by adding a constant to every weight).
WEIGHT_RIDGE = 1e-6


@dataclass(frozen=True, slots=True)
class DetectionFit:
    """limit_power: P_lim (reflectivity / m^2); spread_ln: s; returns: points used;
    nll_per_return: mean negative log-likelihood at the optimum."""

    limit_power: float
    spread_ln: float
    returns: int
    nll_per_return: float

    def range_for(self, reflectivity: float) -> float:
        """Range (m) at which a target of `reflectivity` is detected half the time."""
        return float(np.sqrt(reflectivity / self.limit_power))


def level_counts(
    range_m: npt.NDArray[np.floating],
    intensity: npt.NDArray[np.floating],
    profile: SensorProfile,
    max_range_m: float | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Counts of diffuse returns per (range bin, reflectivity level).

    Args:
        range_m: (N,) ranges, m; intensity: (N,) in the profile's encoding.
        max_range_m: upper end of the window (default the profile's max range).

    Returns:
        counts (B, K), mean range per bin (B,) m, reflectivity per level (K,).
    """
    top = profile.max_range_m if max_range_m is None else max_range_m
    # A stored 0 was detected, so it is taken at the encoding's half step (its floor).
    rho = np.maximum(
        profile.intensity.to_reflectivity(np.asarray(intensity, dtype=np.float32)),
        profile.intensity.detection_floor,
    )
    r = np.asarray(range_m, dtype=np.float64)
    use = (r >= FIT_MIN_RANGE_M) & (r < top) & (rho <= 1.0)
    if not use.any():
        raise ConfigError(
            f"no diffuse returns between {FIT_MIN_RANGE_M} and {top} m to fit "
            "a detection limit on; give frames with far returns."
        )
    r, rho = r[use], rho[use].astype(np.float64)
    levels, level = np.unique(rho, return_inverse=True)
    edges = np.arange(FIT_MIN_RANGE_M, top + RANGE_BIN_M, RANGE_BIN_M)
    b = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, edges.size - 2)
    counts = np.zeros((edges.size - 1, levels.size))
    np.add.at(counts, (b, level), 1.0)
    sums = np.bincount(b, weights=r, minlength=edges.size - 1)
    held = counts.sum(axis=1) > 0
    return counts[held], sums[held] / counts[held].sum(axis=1), levels


def _nll(
    theta: npt.NDArray[np.float64],
    counts: npt.NDArray[np.float64],
    ln_power: npt.NDArray[np.float64],
) -> tuple[float, npt.NDArray[np.float64]]:
    """Negative log-likelihood and its gradient; theta = (w_1..w_K, ln P_lim, ln s)."""
    w, m, s = theta[:-2], theta[-2], np.exp(theta[-1])
    z = (ln_power - m) / s
    log_p = log_ndtr(z)
    a = w[None, :] + log_p
    log_z = np.logaddexp.reduce(a, axis=1)
    pi = np.exp(a - log_z[:, None])
    n_b = counts.sum(axis=1)
    nll = -float((counts * (a - log_z[:, None])).sum()) + WEIGHT_RIDGE * float(w @ w)
    e = counts - n_b[:, None] * pi
    hazard = np.exp(-0.5 * z**2 - 0.5 * np.log(2 * np.pi) - log_p)  # phi(z) / Phi(z)
    grad = np.empty_like(theta)
    grad[:-2] = -e.sum(axis=0) + 2 * WEIGHT_RIDGE * w
    grad[-2] = float((e * hazard).sum()) / s
    grad[-1] = float((e * hazard * z).sum())
    return nll, grad


def fit_detection_limit(
    range_m: npt.NDArray[np.floating],
    intensity: npt.NDArray[np.floating],
    profile: SensorProfile,
    max_range_m: float | None = None,
) -> DetectionFit:
    """Maximum-likelihood (P_lim, s) from clear returns (module docstring).

    Raises:
        ConfigError: no usable returns, or the optimiser did not converge.
    """
    counts, r_bin, levels = level_counts(range_m, intensity, profile, max_range_m)
    ln_power = np.log(levels)[None, :] - 2.0 * np.log(r_bin)[:, None]
    # Start: every level equally likely, the limit at the weakest power seen, s = 1.
    start = np.concatenate([np.zeros(levels.size), [float(ln_power[counts > 0].min()), 0.0]])
    res = minimize(
        _nll, start, args=(counts, ln_power), jac=True, method="L-BFGS-B", options={"maxiter": 5000}
    )
    if not res.success:
        raise ConfigError(f"detection-limit fit did not converge: {res.message}")
    n = int(counts.sum())
    return DetectionFit(float(np.exp(res.x[-2])), float(np.exp(res.x[-1])), n, float(res.fun) / n)
