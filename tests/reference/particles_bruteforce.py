"""Brute-force rain/snow: draw EVERY particle in every beam cone, one beam at a time.

This is the model of `lads.physics.particles` (its module docstring; docs/physics.md §4, §6, §9)
written the slow, literal way, as a reference for the thinned-Poisson fast path:

- The particles in a beam cone form a Poisson process with intensity A(r) N(D),
  A(r) = pi (theta r / 2)^2, N(D) = N0 exp(-Lambda D) for D >= D_min. So per beam
  K ~ Poisson(N_total V) with N_total = N0 / Lambda exp(-Lambda D_min) and
  V = integral_{r_min}^{r0} A(r) dr = pi (theta / 2)^2 (r0^3 - r_min^3) / 3.
- Given K, the particles are i.i.d.: range with pdf proportional to r^2 on [r_min, r0]
  (inverse CDF r = (r_min^3 + U (r0^3 - r_min^3))^(1/3)) and diameter D = D_min + Exp(Lambda).
- Each particle returns P_p = xi(r) rho_p T^2(r) min((D / D_b(r))^2, 1) / r^2 with
  D_b(r) = 1e3 theta r (mm), T^2(r) = exp(-2 alpha r) and the transmitter/receiver overlap
  xi(r): 0 up to r_min = R1, linear to 1 at R2 = overlap_full_m (a step at R1 if R2 = R1,
  LISA's hard cut); the target returns P0 = rho T^2(r0) / r0^2.
- Target detection: a hard step P0 >= P_min ("frame", fixed thresholds), or the sensor's
  soft limit: the target (taken at P_eff = max(P_clear, P_lim)) was seen in clear air
  because its latent receiver noise e ~ N(0, s^2) gave ln P_eff + e >= ln P_lim; that same e,
  drawn by rejection, decides whether ln P0 + e >= ln P_lim in weather.
- strongest: particle return if the strongest particle with P_p >= P_min beats the attenuated
  target (P_p >= max(P0, P_min) when the target is detected); else the target if detected;
  else lost. last: the target if detected; else the farthest particle with P_p >= P_min;
  else lost.
- Kept targets: reflectivity rho T^2(r0), range r0 + N(0, sigma_extra^2) with
  sigma_extra^2 = dR^2 / 2 (P_min / P0 - P_min / P_clear) (clamped at r0 / 2).
  Particle returns: range r, reflectivity P_p r^2.

Only the constants (alpha, N0, Lambda, D_min, theta, r_min, rho_p, P_min, dR) come from the
library (`resolve_optics`), so both implementations share parameters but no sampling code.
At 25 mm/h rain a KITTI frame holds ~10^7 particles; this loop takes seconds per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lads.physics.beams import Beams
from lads.physics.result import Outcome

KEPT, ATTENUATED, PARTICLE, LOST = (
    int(Outcome[n]) for n in ("KEPT", "ATTENUATED", "PARTICLE", "LOST")
)


@dataclass(frozen=True)
class Constants:
    """Every number the model needs, in the units of the particles.py docstring."""

    alpha_per_m: float  # extinction
    n0_per_m3_mm: float  # PSD intercept N0
    slope_per_mm: float  # PSD slope Lambda
    min_diameter_mm: float  # D_min
    divergence_rad: float  # full beam divergence theta
    min_range_m: float  # r_min = R1, overlap starts
    overlap_full_m: float  # R2 >= R1, full overlap
    particle_reflectivity: float  # rho_p
    threshold: float  # P_min, normalised power
    range_accuracy_m: float  # dR
    setting: str = "frame"  # detection rule: "sensor" (soft, conditional) or a hard step
    spread_ln: float = 0.0  # s of the sensor's detection curve

    @classmethod
    def from_optics(cls, optics) -> Constants:
        """Take the constants from a `lads.physics.particles.FrameOptics`."""
        p = optics.particles
        return cls(
            alpha_per_m=p.alpha_per_m,
            n0_per_m3_mm=p.psd.n0_per_m3_mm,
            slope_per_mm=p.psd.slope_per_mm,
            min_diameter_mm=p.psd.min_diameter_mm,
            divergence_rad=p.divergence_rad,
            min_range_m=p.min_range_m,
            # Older ParticleOptics had no overlap ramp: a hard cut at r_min.
            overlap_full_m=getattr(p, "overlap_full_m", p.min_range_m),
            particle_reflectivity=p.particle_reflectivity,
            threshold=optics.threshold,
            range_accuracy_m=optics.range_accuracy_m,
            setting=optics.detection.setting,
            spread_ln=optics.detection.spread_ln,
        )

    def overlap(self, r: np.ndarray) -> np.ndarray:
        """xi(r): 0 up to R1, linear to 1 at R2 (a step at R1 when R2 <= R1)."""
        r1, r2 = self.min_range_m, self.overlap_full_m
        if r2 <= r1:
            return np.where(r > r1, 1.0, 0.0)
        return np.clip((r - r1) / (r2 - r1), 0.0, 1.0)

    @property
    def number_per_m3(self) -> float:
        """N_total: particles per m^3 with D >= D_min."""
        lam = self.slope_per_mm
        return self.n0_per_m3_mm / lam * math.exp(-lam * self.min_diameter_mm)


@dataclass(frozen=True)
class BeamResult:
    """Per input beam: outcome code, output range (m) and output reflectivity."""

    outcome: np.ndarray  # (N,) uint8 Outcome
    range_m: np.ndarray  # (N,) float64; LOST: 0, KEPT: input range
    reflectivity: np.ndarray  # (N,) float64; LOST: 0
    particles_drawn: int  # total particles drawn, for the report
    second_outcome: np.ndarray  # (N,) uint8: dual mode's second (last) return; LOST = none
    second_range_m: np.ndarray  # (N,) float64
    second_reflectivity: np.ndarray  # (N,) float64


def simulate_beam(
    r0: float, rho: float, rho_out: float, c: Constants, mode: str, rng: np.random.Generator
) -> tuple[int, float, float, int]:
    """One beam: (outcome, range, reflectivity, particles drawn) of its strongest or last return.

    rho is the target reflectivity used for power (a stored 0 already replaced by the
    encoding's detection floor); rho_out the one that is attenuated into the output intensity.
    """
    if mode not in ("strongest", "last"):
        raise ValueError(mode)
    strongest, last, _, k = beam_returns(r0, rho, rho_out, c, rng)
    return (*(strongest if mode == "strongest" else last), k)


def beam_returns(
    r0: float, rho: float, rho_out: float, c: Constants, rng: np.random.Generator
) -> tuple[
    tuple[int, float, float], tuple[int, float, float], tuple[int, float, float] | None, int
]:
    """One beam, one draw of its particles: (strongest return, last return, strongest
    detectable particle or None, particles drawn), each return (outcome, range,
    reflectivity); a dual-return sensor reports the first two, or the first and the
    particle where the target is both strongest and last."""
    t2 = lambda r: np.exp(-2.0 * c.alpha_per_m * r)  # noqa: E731
    p_clear = rho / r0**2
    if c.setting == "sensor":
        # The latent noise e ~ N(0, s^2) that let the target be seen in clear air
        # (ln P_eff + e >= ln P_lim), drawn by rejection, decides again in weather.
        p_clear = max(p_clear, c.threshold)
        p_target = p_clear * t2(r0)
        while True:
            e = c.spread_ln * rng.standard_normal()
            if math.log(p_clear) + e >= math.log(c.threshold):
                break
        target_detected = math.log(p_target) + e >= math.log(c.threshold)
    else:
        p_target = p_clear * t2(r0)
        target_detected = p_target >= c.threshold

    # Every particle in the cone between r_min and r0.
    if r0 > c.min_range_m:
        volume = math.pi * (c.divergence_rad / 2) ** 2 * (r0**3 - c.min_range_m**3) / 3.0
        k = rng.poisson(c.number_per_m3 * volume)
    else:
        k = 0
    u = rng.random(k)
    r = (c.min_range_m**3 + u * (r0**3 - c.min_range_m**3)) ** (1.0 / 3.0)
    d = c.min_diameter_mm + rng.exponential(1.0 / c.slope_per_mm, k)
    beam_diameter_mm = 1e3 * c.divergence_rad * r
    fill = np.minimum((d / beam_diameter_mm) ** 2, 1.0)
    p = c.overlap(r) * c.particle_reflectivity * t2(r) * fill / r**2

    target: tuple[int, float, float] = (LOST, 0.0, 0.0)
    if target_detected:
        variance = 0.5 * c.range_accuracy_m**2 * c.threshold * (1 / p_target - 1 / p_clear)
        noisy = r0 + math.sqrt(max(variance, 0.0)) * rng.standard_normal()
        target = (ATTENUATED, max(noisy, 0.5 * r0), rho_out * float(t2(r0)))
    detectable = p >= c.threshold
    strongest, last = target, target
    floor = max(p_target, c.threshold) if target_detected else c.threshold
    beats = p >= floor
    if beats.any():
        j = int(np.argmax(np.where(beats, p, -np.inf)))
        strongest = (PARTICLE, float(r[j]), float(p[j] * r[j] ** 2))
    if not target_detected and detectable.any():
        j = int(np.argmax(np.where(detectable, r, -np.inf)))
        last = (PARTICLE, float(r[j]), float(p[j] * r[j] ** 2))
    best = None
    if detectable.any():
        j = int(np.argmax(np.where(detectable, p, -np.inf)))
        best = (PARTICLE, float(r[j]), float(p[j] * r[j] ** 2))
    return strongest, last, best, k


def simulate(
    beams: Beams,
    rho_out: np.ndarray,
    constants: Constants,
    mode: str,
    rng: np.random.Generator,
    subset: np.ndarray | None = None,
) -> BeamResult:
    """Run every beam (or the `subset` of beam indices) in `mode`.

    Args:
        beams: prepared frame (`lads.physics.beams.prepare_beams`); zero-range beams
            (`beams.active` False) are passed through as KEPT.
        rho_out: (N,) reflectivity of the stored intensity (no detection floor).
        mode: "strongest", "last" or "dual" (the strongest return in the main arrays; the
            last, or the second strongest where they coincide, in the `second_*` arrays).
        subset: beam indices to simulate; the others are left KEPT at their input range.
    """
    n = beams.range_m.size
    outcome = np.full(n, KEPT, dtype=np.uint8)
    range_m = beams.range_m.copy()
    refl = np.zeros(n)
    second = np.full(n, LOST, dtype=np.uint8)
    second_range, second_refl = np.zeros(n), np.zeros(n)
    drawn = 0
    indices = np.arange(n) if subset is None else np.asarray(subset)
    for i in indices:
        if not beams.active[i]:
            continue
        strongest, last, best, k = beam_returns(
            float(beams.range_m[i]),
            float(beams.reflectivity[i]),
            float(rho_out[i]),
            constants,
            rng,
        )
        first = last if mode == "last" else strongest
        outcome[i], range_m[i], refl[i] = first
        if mode == "dual" and last != strongest and last[0] != LOST:
            second[i], second_range[i], second_refl[i] = last
        elif mode == "dual" and strongest[0] == ATTENUATED and best is not None:
            # Velodyne: strongest = last, so the second strongest (the best particle).
            second[i], second_range[i], second_refl[i] = best
        drawn += k
    return BeamResult(outcome, range_m, refl, drawn, second, second_range, second_refl)
