"""Per-beam Monte Carlo of rain and snow, sampled exactly through a thinned Poisson process.

Model (LISA, Kilic et al. 2021, arXiv 2107.07004; docs/physics.md §4, §6 and §9). Each input
point is one beam hitting a hard target of reflectivity rho at range r0; received powers
are normalised so the target gives P0 = rho T^2(r0) / r0^2, T^2(r) = exp(-2 alpha r). The
particles in the beam cone form a Poisson process over range r and diameter D with
intensity A(r) N(D), A(r) = pi (theta r / 2)^2 the beam cross-section for full divergence
theta. A particle returns P_p = rho_p T^2(r) min((D / D_b(r))^2, 1) / r^2, D_b = theta r.

A particle can matter only if P_p >= P_min, i.e. D >= D_thr(r) = D_b r e^(alpha r)
sqrt(P_min / rho_p) (and rho_p T^2 / r^2 >= P_min). Thinning a Poisson process keeps it
Poisson, so we draw only those particles: along the beam with rate
lambda(r) = (N0 / Lambda) exp(-Lambda max(D_thr, D_min)) A(r), range by inverse CDF of
mu(r) = integral lambda, diameter by max(D_thr, D_min) + Exp(Lambda) (memoryless). That is
the same outcome distribution as drawing every particle (~200 per beam at 25 mm/h) while
drawing ~0.1 per beam; `tests/reference/particles_bruteforce.py` draws every one and the
test suite checks the two agree.

Detection (`lads.physics.detection`, docs/physics.md §9.7): a hard target is still detected
with the conditional probability of the sensor's detection curve (default) or by a hard
threshold; a particle needs P_p >= P_min, the sensor's limit.
Decision per beam (strongest return): particle return if the strongest detectable particle
beats the attenuated target; else the target if detected; else lost. Last return: the
target if detected, else the farthest detectable particle, else lost. Dual (Velodyne): the
strongest and the last, or the second strongest where they coincide, so a detectable flake
in front of a detected target is always recorded beside it.
Kept targets: intensity rho T^2 and the extra range noise that the lower SNR brings,
variance (dR^2 / 2) (1 / SNR_w - 1 / SNR_clear), SNR = P_eff / P_min, so clear air is exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.physics.beams import (
    Beams,
    assemble,
    assemble_dual,
    auto_threshold,
    fixed_threshold_in_clear_air,
    unchanged,
)
from lads.physics.detection import Detection, resolve_detection
from lads.physics.kernels import dual_particle_returns
from lads.physics.mie import extinction_per_m
from lads.physics.psd import SIZE_DISTRIBUTIONS, ExponentialPSD
from lads.physics.result import Outcome, WeatherResult
from lads.physics.thinning import ParticleOptics, sample_winning_particles
from lads.sensors.profile import SensorProfile

MODES = ("strongest", "last", "dual")


@dataclass(frozen=True, slots=True)
class ParticleParams:
    """Physical knobs of the rain/snow Monte Carlo; None means "take it from the profile".

    Attributes:
        size_distribution: "marshall_palmer" (rain), "gunn_marshall" or "sekhon_srivastava".
        material: "water" or "ice": refractive index for Mie extinction.
        particle_reflectivity: Lambertian-equivalent backscatter reflectivity rho_p of one
            particle filling the beam, unitless. Fresnel at normal incidence gives 0.0199
            (water) / 0.0173 (ice), LISA's choice; Mie Q_back / 4 of a sphere gives about
            0.4-1.6 for water and 0.06-0.5 for ice (docs/physics.md §2).
            The largest free parameter: calibrated on real snow (lads.calibration.wads).
        n0_scale: multiplier on the size-distribution intercept (LISA's snow: 2).
        diameter_ratio: optical / tabulated diameter; snow tables give melted diameters and
            a flake of density 0.1 g/cm^3 is 2.15 times wider (psd.flake_diameter_ratio).
        min_diameter_mm: smallest particle simulated, mm.
        extinction_scale: effective alpha / Mie alpha in [0.5, 1]; <1 credits forward
            diffraction that stays inside the receiver field of view (docs/physics.md §2).
        beam_divergence_mrad: full-angle divergence; None -> profile.
        min_range_m: R1, bistatic minimum range, nothing nearer is detected; None -> profile.
        overlap_full_m: R2, range of full transmitter/receiver overlap, m; between R1 and R2
            particle returns are scaled by the linear overlap (r - R1) / (R2 - R1). Bright
            hard targets are still seen there, faint particles mostly not. None -> profile
            (R2 = R1 is a hard cut, LISA's model).
        range_accuracy_m: dR, range sigma is dR / sqrt(2 SNR); None -> profile.
        detection_threshold: "sensor" (the profile's detection limit; a hard target
            survives with the conditional probability of docs/physics.md §9.7), "frame"
            (the frame's weakest clear-air return as a hard threshold) or a fixed P_min in
            reflectivity / m^2 (a hard threshold that also drops weaker clear-air returns).
    """

    size_distribution: str = "marshall_palmer"
    material: str = "water"
    particle_reflectivity: float = 0.0199
    n0_scale: float = 1.0
    diameter_ratio: float = 1.0
    min_diameter_mm: float = 0.05
    extinction_scale: float = 1.0
    beam_divergence_mrad: float | None = None
    min_range_m: float | None = None
    range_accuracy_m: float | None = None
    detection_threshold: float | str = "sensor"
    overlap_full_m: float | None = None

    def __post_init__(self) -> None:
        problems = []
        if self.size_distribution not in SIZE_DISTRIBUTIONS:
            problems.append(f"size_distribution must be one of {sorted(SIZE_DISTRIBUTIONS)}")
        if not self.particle_reflectivity > 0:
            problems.append("particle_reflectivity must be > 0")
        if not (self.n0_scale > 0 and self.diameter_ratio > 0 and self.min_diameter_mm > 0):
            problems.append("n0_scale, diameter_ratio and min_diameter_mm must be > 0")
        if not 0.5 <= self.extinction_scale <= 1.0:
            problems.append("extinction_scale must lie in [0.5, 1]")
        for key in ("beam_divergence_mrad", "range_accuracy_m"):
            value = getattr(self, key)
            if value is not None and not value > 0:
                problems.append(f"{key} must be > 0 when given")
        if self.min_range_m is not None and not self.min_range_m >= 0:
            problems.append("min_range_m must be >= 0 when given")
        if self.overlap_full_m is not None and not (
            self.overlap_full_m >= (self.min_range_m or 0.0) and math.isfinite(self.overlap_full_m)
        ):
            problems.append("overlap_full_m must be finite and >= min_range_m when given")
        if problems:
            raise ConfigError("ParticleParams: " + "; ".join(problems) + ".")
        resolve_detection(self.detection_threshold, 1.0, 1.0, 1.0)  # raises if malformed

    def psd(self, rate_mm_h: float) -> ExponentialPSD:
        """Size distribution of optical diameters at a rate (mm/h)."""
        table = SIZE_DISTRIBUTIONS[self.size_distribution](
            rate_mm_h, n0_scale=self.n0_scale, min_diameter_mm=self.min_diameter_mm
        )
        if self.diameter_ratio == 1.0:
            return table
        scaled = table.scaled_diameter(self.diameter_ratio)
        return ExponentialPSD(scaled.n0_per_m3_mm, scaled.slope_per_mm, self.min_diameter_mm)


@dataclass(frozen=True, slots=True)
class FrameOptics:
    """Per-frame constants: the particle process plus detection rule and range accuracy."""

    particles: ParticleOptics
    detection: Detection
    range_accuracy_m: float

    @property
    def threshold(self) -> float:
        """P_min a particle return needs, reflectivity / m^2."""
        return self.detection.threshold


def resolve_optics(
    beams: Beams, sensor: SensorProfile, rate_mm_h: float, params: ParticleParams
) -> FrameOptics:
    """Fix every constant of the model for one frame (rate_mm_h > 0)."""
    psd = params.psd(rate_mm_h)
    alpha = params.extinction_scale * extinction_per_m(psd, params.material, sensor.wavelength_nm)
    # Tabulate to a fixed round range so consecutive frames share one cached table.
    farthest = max(sensor.max_range_m, float(beams.range_m.max(initial=0.0)))
    min_range = _pick(params.min_range_m, sensor.min_range_m)
    particles = ParticleOptics(
        psd=psd,
        alpha_per_m=alpha,
        divergence_rad=1e-3 * _pick(params.beam_divergence_mrad, sensor.beam_divergence_mrad),
        min_range_m=min_range,
        particle_reflectivity=params.particle_reflectivity,
        max_range_m=max(10.0 * math.ceil(farthest / 10.0), min_range + 10.0),
        overlap_full_m=max(_pick(params.overlap_full_m, sensor.overlap_full_m), min_range),
    )
    detection = resolve_detection(
        params.detection_threshold,
        sensor.detection.power,
        sensor.detection.spread_ln,
        auto_threshold(beams),
    )
    return FrameOptics(
        particles, detection, _pick(params.range_accuracy_m, sensor.range_accuracy_m)
    )


def _pick(value: float | None, default: float) -> float:
    return default if value is None else value


def simulate_particles(
    beams: Beams,
    sensor: SensorProfile,
    *,
    rate_mm_h: float,
    rng: np.random.Generator,
    mode: str,
    params: ParticleParams,
) -> WeatherResult:
    """Rain or snow on one frame; see the module docstring for the model.

    Args:
        beams: prepared input (lads.physics.beams.prepare_beams).
        sensor: profile the frame was recorded with.
        rate_mm_h: precipitation rate, mm/h (water-equivalent for snow), >= 0.
        rng: the frame's generator; the same generator state gives the same bytes.
        mode: "strongest", "last" or "dual" (strongest and, where it differs, last).
        params: physical knobs.
    """
    if mode not in MODES:
        raise ConfigError(f"mode '{mode}': expected one of {MODES}.")
    if not (math.isfinite(rate_mm_h) and rate_mm_h >= 0):
        raise ConfigError(f"rate_mm_h={rate_mm_h!r}: expected a finite rate >= 0 in mm/h.")
    n = beams.range_m.size
    if n == 0:
        return unchanged(beams, sensor)
    if rate_mm_h == 0:
        rule = resolve_detection(
            params.detection_threshold,
            sensor.detection.power,
            sensor.detection.spread_ln,
            auto_threshold(beams),
        )
        return fixed_threshold_in_clear_air(beams, sensor, rule) or unchanged(beams, sensor)
    optics = resolve_optics(beams, sensor, rate_mm_h, params)
    alpha = optics.particles.alpha_per_m
    r0 = np.where(beams.active, beams.range_m, 0.0)
    two_way_ln = -2.0 * alpha * r0
    transmission = np.exp(two_way_ln)
    detected, target_power = optics.detection.targets_detected(
        beams.clear_power, two_way_ln, beams.active, rng, transmission
    )

    if mode == "dual":
        return _dual(beams, sensor, optics, detected, target_power, transmission, rng)
    return _single_return(
        beams, sensor, optics, detected, target_power, transmission, r0, rng, mode
    )


def _single_return(
    beams: Beams,
    sensor: SensorProfile,
    optics: FrameOptics,
    detected: npt.NDArray[np.bool_],
    target_power: npt.NDArray[np.float64],
    transmission: npt.NDArray[np.float64],
    r0: npt.NDArray[np.float64],
    rng: np.random.Generator,
    mode: str,
) -> WeatherResult:
    """The "strongest" or "last" return of each beam: the winning particle or the
    attenuated target (`detected`, at `target_power`), else lost. `r0`: target ranges (m),
    0 for inactive beams."""
    n = beams.range_m.size
    # Strongest: a particle matters if it is detectable and beats the detected target.
    # Last: only on beams whose target is lost.
    if mode == "strongest":
        floor = np.where(detected, np.maximum(target_power, optics.threshold), optics.threshold)
        searched = r0
    else:
        floor = np.full(n, optics.threshold)
        searched = np.where(detected, 0.0, r0)
    owner, r_p, p_p = sample_winning_particles(optics.particles, searched, floor, rng)
    best_r, best_p, has_particle = _best_per_beam(n, owner, r_p, p_p, mode)
    particle_wins = has_particle & beams.active
    kept = detected & ~particle_wins

    outcome = np.full(n, Outcome.KEPT, dtype=np.uint8)
    outcome[beams.active] = Outcome.LOST
    outcome[kept] = Outcome.ATTENUATED
    outcome[particle_wins] = Outcome.PARTICLE

    out_range, out_refl = _target_returns(
        beams, sensor, optics, target_power, transmission, kept, rng
    )
    out_range[particle_wins] = best_r[particle_wins]
    out_refl[particle_wins] = best_p[particle_wins] * best_r[particle_wins] ** 2
    return assemble(
        beams,
        sensor,
        outcome=outcome,
        range_m=out_range,
        reflectivity=out_refl,
        extinction_per_m=optics.particles.alpha_per_m,
        detection_threshold=optics.threshold,
    )


def _target_returns(
    beams: Beams,
    sensor: SensorProfile,
    optics: FrameOptics,
    target_power: npt.NDArray[np.float64],
    transmission: npt.NDArray[np.float64],
    kept: npt.NDArray[np.bool_],
    rng: np.random.Generator,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(N,) range (m) and reflectivity of every beam's target return in weather: kept beams
    get the SNR range noise, every beam its attenuated reflectivity rho T^2."""
    out_range = beams.range_m.copy()
    out_refl = sensor.intensity.to_reflectivity(beams.intensity) * transmission
    clear_power = optics.detection.effective_power(beams.clear_power)
    noisy = out_range[kept] + _extra_range_noise(optics, clear_power, target_power, kept, rng)
    # sigma <= dR / sqrt(2) is centimetres; the clamp only guards returns near the origin.
    out_range[kept] = np.maximum(noisy, 0.5 * beams.range_m[kept])
    return out_range, out_refl


def _dual(
    beams: Beams,
    sensor: SensorProfile,
    optics: FrameOptics,
    detected: npt.NDArray[np.bool_],
    target_power: npt.NDArray[np.float64],
    transmission: npt.NDArray[np.float64],
    rng: np.random.Generator,
) -> WeatherResult:
    """Dual return (Velodyne's convention): every beam's strongest return and its last, or
    the second strongest where the strongest is also the last.

    All detectable particles are drawn once (floor P_min on the whole beam), so both returns
    come from one realisation: the strongest is the strongest particle if it beats the
    detected target (else the target), the last the target if detected (else the farthest
    particle); a detected target that is both has the strongest particle in front as its
    second. A beam with two returns appears twice in source_index, strongest first.
    """
    n = beams.range_m.size
    r0 = np.where(beams.active, beams.range_m, 0.0)
    owner, r_p, p_p = sample_winning_particles(
        optics.particles, r0, np.full(n, optics.threshold), rng
    )
    s_r, s_p, has_s = _best_per_beam(n, owner, r_p, p_p, "strongest")
    l_r, l_p, has_l = _best_per_beam(n, owner, r_p, p_p, "last")
    target_range, target_refl = _target_returns(
        beams, sensor, optics, target_power, transmission, detected, rng
    )
    # Target strongest and last: Velodyne's dual mode then reports the second strongest,
    # the strongest flake in front (the WADS recording shows them, lads.calibration.wads).
    codes1, range1, refl1, codes2, range2, refl2 = dual_particle_returns(
        beams.active,
        detected,
        target_power,
        target_range,
        target_refl,
        s_r,
        s_p,
        has_s,
        l_r,
        l_p,
        has_l,
    )
    common = {
        "extinction_per_m": optics.particles.alpha_per_m,
        "detection_threshold": optics.threshold,
    }
    return assemble_dual(
        beams, sensor, first=(codes1, range1, refl1), second=(codes2, range2, refl2), **common
    )


def _best_per_beam(
    n: int,
    owner: npt.NDArray[np.int64],
    r_p: npt.NDArray[np.float64],
    p_p: npt.NDArray[np.float64],
    mode: str,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Per beam: range and power of the strongest (or farthest) particle found."""
    best_r, best_p = np.zeros(n), np.zeros(n)
    has = np.zeros(n, dtype=bool)
    if owner.size:
        key = p_p if mode == "strongest" else r_p
        order = np.lexsort((key, owner))
        last = order[np.r_[owner[order][1:] != owner[order][:-1], True]]
        best_r[owner[last]], best_p[owner[last]] = r_p[last], p_p[last]
        has[owner[last]] = True
    return best_r, best_p, has


# Noise below this sigma cannot show in float32 coordinates (ulp at 10 m is ~1 um).
NEGLIGIBLE_SIGMA_M = 1e-7


def _extra_range_noise(
    optics: FrameOptics,
    clear_power: npt.NDArray[np.float64],
    weather_power: npt.NDArray[np.float64],
    kept: npt.NDArray[np.bool_],
    rng: np.random.Generator,
) -> npt.NDArray[np.float64]:
    """Range noise the SNR drop adds to kept beams, (n_kept,) m.

    sigma = dR / sqrt(2 SNR) with SNR = P / P_min, so the extra variance is
    dR^2 P_min / 2 (1/P_w - 1/P_clear); draws below NEGLIGIBLE_SIGMA_M are skipped.
    """
    idx = np.flatnonzero(kept)
    variance = (
        0.5
        * optics.range_accuracy_m**2
        * optics.threshold
        * np.maximum(1.0 / weather_power[idx] - 1.0 / clear_power[idx], 0.0)
    )
    sigma = np.sqrt(variance)
    noise = np.zeros(idx.size)
    visible = sigma > NEGLIGIBLE_SIGMA_M
    noise[visible] = sigma[visible] * rng.standard_normal(int(visible.sum()))
    return noise
