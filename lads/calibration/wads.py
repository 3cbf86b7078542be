"""Fit the physical knobs of the snow model to real falling snow (WADS, label 110).

What is compared (docs/physics.md §5.3). WADS holds real snow with point-wise labels: 110 is
active falling snow, 111 accumulated snow. Removing the 110 points leaves the "clear" scene
(every remaining point is one beam with a hard target); we let it snow on that scene and
compare the simulated particle returns with the real 110 points: their share of the points,
their range distribution (two-sample Kolmogorov-Smirnov distance) and their intensity.

WADS is a dual-return recording (measured here, not documented anywhere we have): ~42 % of
rows are exact duplicates, every duplicate's partner sits 46-64 rows away (the other return
block of the same firing), 86 % of non-snow rows are duplicated (strongest = last return, one
target) but only 30 % of snow rows; and 99 % of the non-duplicated snow points have a farther
return on the same ray (the target behind the flake). Velodyne dual mode stores the last and
the strongest return, or the second-strongest when the strongest is also the last. A flake
in front of a target is therefore recorded whenever it is the strongest particle above the
threshold, whether or not it beats the target: `simulate(mode="dual")` is `weather.snow()` in
that dual mode; `mode="strongest"` is a single-return sensor, where a flake must beat the
target. Duplicated snow rows (a flake
that is both returns: beams with no target behind, mostly upward beams into the sky) cannot
be simulated from the clear scene, which has no beam there; they are reported, not fitted.

The knobs (`SnowKnobs`) and their physics:

- particle_reflectivity rho_p: Lambertian-equivalent backscatter reflectivity of one flake
  filling the beam. Fresnel at normal incidence gives 0.0173 for ice (LISA); Mie Q_back / 4
  of an ice sphere gives about 0.45-0.5 at 5-50 um and 0.06-0.17 at 0.5-2 mm (docs/physics.md
  §2); a real flake is an aggregate of needles and plates whose backscatter lies between.
  It sets how far out a flake is detectable (P_p = rho_p fill T^2 / r^2 >= P_min) and the
  intensity a flake return carries (rho_p fill T^2: real snow reads ~0, which bounds rho_p
  from above).
- beam_divergence_mrad theta: full-angle divergence. The beam diameter theta r sets the
  fill factor (D / theta r)^2 of a flake (wider beam: dimmer flakes, but more of them in the
  cone, volume ~ theta^2 r^3). Automotive datasheets give 1-3 mrad; bounds 0.5-10.
- min_range_m R1 and overlap_full_m R2: bistatic transmitter/receiver geometry. Nothing is
  seen before the fields of view start to overlap at R1; the overlap grows ~linearly to 1 at
  R2. Bright hard targets are still detected inside R2, faint flakes mostly not, which is
  why real snow starts at ~2 m and its density per r^2 rises up to ~5 m.
- detection_threshold P_lim: the sensor's detection limit, normalised power (reflectivity /
  m^2): a flake return needs P_p >= P_lim, and hard targets survive the snow with the
  conditional probability of `lads.physics.detection` (clear air loses nothing). A sensor
  that sees 10 % reflectivity out to r10 has P_lim = 0.1 / r10^2. WADS' sensor model is not
  confirmed, so its limit is fitted here and written into wads64.yaml; other sensors take
  theirs from a datasheet. Only rho_p / P_lim sets the flake count; the flakes' intensity
  (real flakes read ~0) sets rho_p.

The snowfall rate of WADS is not recorded per frame (nor in any document we hold). The
number of detectable flakes grows with the rate and with rho_p / P_min alike, so the rate is
a nuisance parameter: we fix it at ASSUMED_RATE_MM_H and report how the fit moves with it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import optimize, stats

from lads.calibration.wads_frames import (
    ACCUMULATED_SNOW,
    FALLING_SNOW,
    PERCENTILES,
    SnowScene,
    WadsFrame,
    duplicate_mask,
    load_frame,
    load_sequence,
    percentiles,
    real_snow_stats,
    scene_from_frame,
)
from lads.calibration.wads_knobs import (
    BOUNDS,
    FITTED_SNOW_KNOBS,
    SENSOR,
    SnowKnobs,
    knob_vector,
    knobs_from_vector,
)
from lads.errors import ConfigError
from lads.physics.particles import ParticleParams
from lads.physics.result import Outcome
from lads.physics.weather import LISA_SNOW, SNOW_DEFAULTS, snow, with_overrides
from lads.sensors.profile import SensorProfile, load_profile

MODES = ("dual", "strongest")

# Water-equivalent snowfall rate assumed for the WADS frames, mm/h. Not recorded per frame.
# WADS was collected in "severe winter weather"; 2.5 mm/h water equivalent is ~2.5 cm/h of
# fresh snow at a 10:1 snow-to-liquid ratio, the usual threshold of "heavy" snowfall rates.
# Treated as a nuisance parameter: see `rate_sensitivity`.
ASSUMED_RATE_MM_H = 2.5

# LISA's settings (docs/physics.md §4, paper code / pylisa) are `LISA_SNOW`, imported above.
# The Hahner fork of LISA: r_max 120 m (threshold 0.9 / 120^2) and r_min 0.9 m.
LISA_HAHNER_SNOW = with_overrides(LISA_SNOW, min_range_m=0.9, detection_threshold=0.9 / 120.0**2)


@dataclass(frozen=True, slots=True)
class SimulatedSnow:
    """Particle returns of one simulated frame: ranges (m), intensities (0-255), share."""

    range_m: npt.NDArray[np.float64]
    intensity: npt.NDArray[np.float32]
    fraction: float
    detection_threshold: float


def simulate(
    scene: SnowScene,
    params: ParticleParams,
    *,
    rate_mm_h: float,
    rng: np.random.Generator,
    mode: str = "dual",
    sensor: SensorProfile | str = SENSOR,
) -> SimulatedSnow:
    """Let it snow on the clear scene with `weather.snow()`; return the simulated flakes.

    mode "dual" (as WADS records): the library's dual return, a beam's strongest return and
    its last (or second strongest), so a beam's strongest flake above the limit is recorded
    whether or not it beats the target; "strongest": a single-return sensor, where a flake
    must beat the target. fraction = flake returns / output points, as
    `SnowScene.target_fraction` counts the real frame. Targets are detected by the rule
    `params.detection_threshold` names (`lads.physics.detection`).

    Raises:
        ConfigError: mode not in MODES.
    """
    if mode not in MODES:
        raise ConfigError(f"mode {mode!r}: expected one of {MODES}.")
    profile = load_profile(sensor) if isinstance(sensor, str) else sensor
    res = snow(
        scene.clear_xyz,
        scene.clear_intensity,
        rate_mm_h=rate_mm_h,
        sensor=profile,
        rng=rng,
        params=params,
        mode=mode,
    )
    flake = res.outcome == Outcome.PARTICLE
    r = np.linalg.norm(res.xyz[flake].astype(np.float64), axis=1)
    return SimulatedSnow(r, res.intensity[flake], float(flake.mean()), res.detection_threshold)


def compare(
    real_range_m: npt.NDArray[np.float64],
    real_intensity: npt.NDArray[np.float32],
    real_fraction: float,
    sim_range_m: npt.NDArray[np.float64],
    sim_intensity: npt.NDArray[np.float32],
    sim_fraction: float,
) -> dict[str, Any]:
    """Range KS distance, share ratio and intensity of simulated vs real flakes."""
    if sim_range_m.size == 0:
        ks, p = 1.0, 0.0
    else:
        test = stats.ks_2samp(real_range_m, sim_range_m)
        ks, p = float(test.statistic), float(test.pvalue)
    zero_real = float((real_intensity == 0).mean()) if real_intensity.size else math.nan
    zero_sim = float((sim_intensity == 0).mean()) if sim_intensity.size else math.nan
    return {
        "ks_range": round(ks, 4),
        "ks_pvalue": p,
        "fraction_real": round(real_fraction, 5),
        "fraction_sim": round(sim_fraction, 5),
        "fraction_ratio": round(sim_fraction / real_fraction, 4) if real_fraction else math.nan,
        "range_pct_real": percentiles(real_range_m),
        "range_pct_sim": percentiles(sim_range_m),
        "intensity_zero_share_real": round(zero_real, 4),
        "intensity_zero_share_sim": round(zero_sim, 4),
        "n_real": int(real_range_m.size),
        "n_sim": int(sim_range_m.size),
    }


def evaluate(
    scenes: Sequence[SnowScene],
    params: ParticleParams,
    *,
    rate_mm_h: float = ASSUMED_RATE_MM_H,
    mode: str = "dual",
    seeds: Sequence[int] = (0,),
    sensor: SensorProfile | str = SENSOR,
) -> dict[str, Any]:
    """Pooled comparison over scenes and seeds (every seed simulates every scene)."""
    sim_r, sim_i, real_r, real_i, fs, fr = [], [], [], [], [], []
    for k, scene in enumerate(scenes):
        real_r.append(scene.snow_range_m)
        real_i.append(scene.snow_intensity)
        fr.append(scene.target_fraction)
        for seed in seeds:
            rng = np.random.default_rng([seed, k])
            sim = simulate(scene, params, rate_mm_h=rate_mm_h, rng=rng, mode=mode, sensor=sensor)
            sim_r.append(sim.range_m)
            sim_i.append(sim.intensity)
            fs.append(sim.fraction)
    return compare(
        np.concatenate(real_r),
        np.concatenate(real_i),
        float(np.mean(fr)),
        np.concatenate(sim_r),
        np.concatenate(sim_i),
        float(np.mean(fs)),
    )


def loss(result: dict[str, Any], intensity_weight: float = 1.0) -> float:
    """KS range distance + |log(sim / real share)| + w |zero-intensity share difference|.

    The intensity term separates rho_p from P_min: in dual mode the flake count depends on
    their ratio only, but a flake's intensity is rho_p fill T^2, and real flakes read 0.
    """
    ratio = result["fraction_ratio"]
    share = abs(math.log(ratio)) if ratio > 0 else 10.0
    zero = result["intensity_zero_share_sim"]
    zero_term = 1.0 if math.isnan(zero) else abs(zero - result["intensity_zero_share_real"])
    return result["ks_range"] + share + intensity_weight * zero_term


@dataclass(frozen=True, slots=True)
class FitResult:
    knobs: SnowKnobs
    loss: float
    evaluations: int
    grid_best: SnowKnobs
    grid_loss: float


def fit(
    scenes: Sequence[SnowScene],
    *,
    rate_mm_h: float = ASSUMED_RATE_MM_H,
    mode: str = "dual",
    seeds: Sequence[int] = (0, 1),
    fit_threshold: bool = True,
    base: ParticleParams = SNOW_DEFAULTS,
    max_evaluations: int = 250,
) -> FitResult:
    """Coarse grid, then Nelder-Mead, on `loss` with common random numbers (fixed seeds).

    Grid: rho_p x theta x P_min (or auto) at R1 = 2 m, R2 = 5 m (where real snow starts and
    where its density per r^2 peaks); then all five knobs by Nelder-Mead within BOUNDS.
    """
    objective = _Objective(scenes, rate_mm_h, mode, seeds, fit_threshold, base)
    grid = _start_grid(fit_threshold)
    values = [objective(x) for x in grid]
    best = int(np.argmin(values))
    x0 = grid[best]
    step = np.array([0.3, 0.2, 0.5, 0.5, 0.3])
    simplex = np.vstack([x0] + [x0 + np.diag(step)[i] for i in range(5)])
    res = optimize.minimize(
        objective,
        x0,
        method="Nelder-Mead",
        options={
            "initial_simplex": simplex,
            "maxfev": max_evaluations,
            "xatol": 1e-3,
            "fatol": 1e-4,
        },
    )
    x_best = res.x if res.fun < values[best] else x0
    return FitResult(
        knobs=knobs_from_vector(x_best, fit_threshold),
        loss=float(min(res.fun, values[best])),
        evaluations=objective.count,
        grid_best=knobs_from_vector(x0, fit_threshold),
        grid_loss=float(values[best]),
    )


def _start_grid(fit_threshold: bool) -> list[npt.NDArray[np.float64]]:
    """The grid's knob vectors: rho_p x theta x P_lim at R1 = 2 m, R2 = 5 m."""
    thresholds = [1e-6, 3e-6, 1e-5, 3e-5] if fit_threshold else [1e-6]
    return [
        np.array([math.log10(rho), math.log10(th), 2.0, 3.0, math.log10(pm)])
        for rho in (0.0173, 0.05, 0.15, 0.5, 1.5)
        for th in (1.0, 3.0, 6.0)
        for pm in thresholds
    ]


@dataclass
class _Objective:
    """`loss` of the knobs at a knob vector, counting its evaluations."""

    scenes: Sequence[SnowScene]
    rate_mm_h: float
    mode: str
    seeds: Sequence[int]
    fit_threshold: bool
    base: ParticleParams
    count: int = 0

    def __call__(self, x: npt.NDArray[np.float64]) -> float:
        self.count += 1
        knobs = knobs_from_vector(x, self.fit_threshold)
        res = evaluate(
            self.scenes,
            knobs.params(self.base),
            rate_mm_h=self.rate_mm_h,
            mode=self.mode,
            seeds=self.seeds,
            sensor=knobs.sensor(),
        )
        # Soft wall outside the bounds, so Nelder-Mead does not wander on a flat plateau.
        clipped = knob_vector(knobs)
        wall = float(np.abs(x - clipped)[: 5 if self.fit_threshold else 4].sum())
        return loss(res) + wall


def rate_sensitivity(
    scenes: Sequence[SnowScene],
    knobs: SnowKnobs,
    rates_mm_h: Sequence[float],
    *,
    mode: str = "dual",
    seeds: Sequence[int] = (0,),
    base: ParticleParams = SNOW_DEFAULTS,
) -> list[dict[str, Any]]:
    """The fitted knobs at other snowfall rates, and rho_p refitted alone at each rate."""
    out = []
    profile = knobs.sensor()
    for rate in rates_mm_h:
        fixed = evaluate(
            scenes, knobs.params(base), rate_mm_h=rate, mode=mode, seeds=seeds, sensor=profile
        )

        def f(log_rho: float, rate: float = rate) -> float:
            k = with_overrides(knobs.params(base), particle_reflectivity=10**log_rho)
            result = evaluate(scenes, k, rate_mm_h=rate, mode=mode, seeds=seeds, sensor=profile)
            return loss(result)

        lo, hi = (math.log10(v) for v in BOUNDS["particle_reflectivity"])
        best = optimize.minimize_scalar(
            f, bounds=(lo, hi), method="bounded", options={"xatol": 0.02}
        )
        out.append(
            {
                "rate_mm_h": rate,
                "fitted_knobs": {
                    "ks_range": fixed["ks_range"],
                    "fraction_ratio": fixed["fraction_ratio"],
                },
                "rho_p_refit": round(10 ** float(best.x), 4),
                "loss_refit": round(float(best.fun), 4),
            }
        )
    return out


# Re-exported for the benchmark and the tests, which read a frame and fit it in one place,
# and for the importers of the knobs from before they moved to wads_knobs.
__all__ = [
    "ACCUMULATED_SNOW",
    "BOUNDS",
    "FALLING_SNOW",
    "FITTED_SNOW_KNOBS",
    "PERCENTILES",
    "SENSOR",
    "SnowKnobs",
    "SnowScene",
    "WadsFrame",
    "duplicate_mask",
    "load_frame",
    "load_sequence",
    "real_snow_stats",
    "scene_from_frame",
]
