"""Which returns the sensor detects: its detection limit and how weather takes points away.

Equations (docs/physics.md §9.7). Powers are normalised as in `lads.physics.beams`: a hard
target of reflectivity rho at range r returns P0 = rho / r^2 in clear air and
P_w = P0 T^2 in weather, T^2 = exp(-2 alpha r).

- The sensor's **detection limit** P_lim = rho_lim / r_lim^2 comes from its datasheet (a
  target of reflectivity rho_lim is seen out to r_lim; `SensorProfile.detection`). Receiver
  noise and the scatter of a stored intensity around the true one make detection soft:
  a return of true power P is detected with probability
      p(P) = Phi((ln P - ln P_lim) / s),
  s = `spread_ln` of the profile.
- A point of the frame **was detected in clear air**, so it survives weather with the
  conditional probability
      q = p(P_eff T^2) / p(P_eff),      P_eff = max(P0, P_lim).
  Clear air (T = 1) gives q = 1: nothing the frame shows is lost. Stored intensities often
  say less than the power detection needed (KITTI stores remission 0 for a large share of
  its returns beyond 40 m), so a point is never taken as weaker than the limit: the datasheet
  and the fact of detection outrank a stored intensity below the encoding's resolution.
- **Faint (volume) returns** (drops, flakes, fog) carry no clear-air evidence and are seen
  after the transmitter/receiver overlap ramp that gives them their near-range onset
  (`lads.physics.weather.FAINT_ONSET_M`). A fog echo is detected with probability p(P_f): it
  is the same on every beam of a frame, and a hard step would switch fog returns on for all
  beams or for none. Drops and flakes need P_p >= P_lim (a hard step, which the exact thinned
  particle sampler needs; their powers already spread over decades).

Two explicit alternatives (`DETECTION_SETTINGS`): "frame", the threshold calibrated to the
frame (its weakest clear-air return, a hard step), which loses almost nothing in rain; and a
fixed number P_min (reflectivity / m^2, a hard step, LISA's model), which also drops clear-air
returns weaker than P_min.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import log_ndtr, ndtr

from lads.errors import ConfigError
from lads.physics.kernels import APPROX, EXACT, survival_screen

DETECTION_SETTINGS = ("sensor", "frame")
# Phi(z) for z beyond this is 1 in float64 (1 - Phi(8.3) < 2^-53): survival is exactly 1.
CERTAIN_Z = 8.3


@dataclass(frozen=True, slots=True)
class Detection:
    """The detection rule of one frame.

    Attributes:
        setting: "sensor", "frame" or "fixed".
        threshold: P_lim (sensor) or P_min (frame, fixed), reflectivity / m^2; faint returns
            need at least this power.
        spread_ln: s of the soft detection curve in ln-power units; 0 = hard step.
    """

    setting: str
    threshold: float
    spread_ln: float

    def effective_power(self, clear_power: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """(N,) clear-air power a detected target is taken to have (reflectivity / m^2)."""
        if self.setting == "sensor":
            return np.maximum(clear_power, self.threshold)
        return clear_power

    def targets_detected(
        self,
        clear_power: npt.NDArray[np.float64],
        two_way_ln: npt.NDArray[np.float64],
        active: npt.NDArray[np.bool_],
        rng: np.random.Generator,
        transmission: npt.NDArray[np.float64] | None = None,
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
        """Which hard targets are still detected, and their effective weather power.

        Args:
            clear_power: (N,) P0 = rho / r^2, reflectivity / m^2 (inactive beams: +inf).
            two_way_ln: (N,) ln T^2 = -2 alpha r, <= 0.
            active: (N,) beams the weather acts on.
            rng: the frame's generator; "sensor" draws one uniform per uncertain beam.
            transmission: (N,) exp(two_way_ln) where the caller has it already.

        Returns:
            detected (N,) bool and P_eff T^2 (N,) float64.
        """
        effective = self.effective_power(clear_power)
        power = effective * (np.exp(two_way_ln) if transmission is None else transmission)
        if self.setting != "sensor":
            return active & (power >= self.threshold), power
        return _draw_survivals(effective, two_way_ln, active, self, rng), power

    def faint_detected(
        self, power: npt.NDArray[np.float64], rng: np.random.Generator
    ) -> npt.NDArray[np.bool_]:
        """(N,) whether volume returns of power P (reflectivity / m^2) are detected: with
        probability p(P) under "sensor" (one uniform per beam where 0 < p < 1), else P >= P_min.
        """
        if self.setting != "sensor":
            return power >= self.threshold
        with np.errstate(divide="ignore"):
            z = np.log(power / self.threshold) / self.spread_ln
        detected = z >= CERTAIN_Z
        uncertain = np.flatnonzero((z > -CERTAIN_Z) & (z < CERTAIN_Z))
        if uncertain.size:
            detected[uncertain] = rng.random(uncertain.size) < ndtr(z[uncertain])
        return detected


def target_survival(
    effective_power: npt.NDArray[np.float64],
    two_way_ln: npt.NDArray[np.float64],
    limit_power: float,
    spread_ln: float,
) -> npt.NDArray[np.float64]:
    """q = Phi(z - d) / Phi(z), z = ln(P_eff / P_lim) / s, d = -ln T^2 / s; (N,) in [0, 1].

    Beams with z - d beyond CERTAIN_Z survive with probability exactly 1 and cost nothing.
    """
    z, z_weather = _z_scores(effective_power, two_way_ln, limit_power, spread_ln)
    out = np.ones_like(z)
    doubtful = np.flatnonzero(np.isfinite(z) & (z_weather < CERTAIN_Z))
    if doubtful.size:
        out[doubtful] = _survival_ratio(z[doubtful], z_weather[doubtful])
    return out


def _z_scores(
    effective_power: npt.NDArray[np.float64],
    two_way_ln: npt.NDArray[np.float64],
    limit_power: float,
    spread_ln: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(N,) z = ln(P_eff / P_lim) / s in clear air and z - d in weather."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.log(effective_power / limit_power) / spread_ln
    return z, z + two_way_ln / spread_ln


def _survival_ratio(
    z: npt.NDArray[np.float64], z_weather: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """(M,) Phi(z_weather) / Phi(z), each element computed on its own (subsets agree)."""
    # Phi(z) >= 1/2 for z >= 0 (every target under the sensor rule, P_eff >= P_lim): the
    # plain ratio is exact there and cheaper; a z < 0 (another caller) takes the log form.
    plain = z >= 0.0
    ratio = np.empty(z.size)
    # Phi(z) is exactly 1 beyond CERTAIN_Z: the ratio is then Phi(z - d) itself.
    sure = z >= CERTAIN_Z
    ratio[sure] = ndtr(z_weather[sure])
    part = plain & ~sure
    ratio[part] = ndtr(z_weather[part]) / ndtr(z[part])
    ratio[~plain] = np.exp(log_ndtr(z_weather[~plain]) - log_ndtr(z[~plain]))
    return ratio


# Phi tabulated for the screen: rows PHI_STEPS_PER_UNIT per unit of z from PHI_TABLE_START.
# Linear interpolation errs by at most phi(1) / (8 steps^2) = 4.6e-7 on Phi, so by at most
# 1.9e-6 on q = Phi(z_w) / Phi(z) with Phi(z) >= 1/2; the tolerance keeps a 5x margin.
PHI_TABLE_START = -9.0  # Phi(-9) = 1.1e-19: taken as 0 below
PHI_STEPS_PER_UNIT = 256.0
SCREEN_TOLERANCE = 1e-5


@functools.lru_cache(maxsize=1)
def _phi_table() -> npt.NDArray[np.float64]:
    rows = math.ceil((CERTAIN_Z - PHI_TABLE_START) * PHI_STEPS_PER_UNIT) + 2
    table = ndtr(PHI_TABLE_START + np.arange(rows) / PHI_STEPS_PER_UNIT)
    table.flags.writeable = False
    return table


def _draw_survivals(
    effective: npt.NDArray[np.float64],
    two_way_ln: npt.NDArray[np.float64],
    active: npt.NDArray[np.bool_],
    rule: Detection,
    rng: np.random.Generator,
) -> npt.NDArray[np.bool_]:
    """(N,) detected: u < q with one uniform per active beam whose q < 1, in beam order.

    The decisions equal those of the exact q (`target_survival`): the tabulated q decides
    wherever the draw lies beyond SCREEN_TOLERANCE of it, the exact q everywhere else.
    """
    z, z_weather = _z_scores(effective, two_way_ln, rule.threshold, rule.spread_ln)
    q, state = survival_screen(
        z,
        z_weather,
        active,
        _phi_table(),
        PHI_TABLE_START,
        PHI_STEPS_PER_UNIT,
        CERTAIN_Z,
        SCREEN_TOLERANCE,
    )
    exact = np.flatnonzero(state == EXACT)
    if exact.size:
        q[exact] = _survival_ratio(z[exact], z_weather[exact])
    uncertain = np.flatnonzero((state == APPROX) | ((state == EXACT) & (q < 1.0)))
    detected = active.copy()
    if not uncertain.size:
        return detected
    u = rng.random(uncertain.size)
    q_u = q[uncertain]
    slack = np.where(state[uncertain] == APPROX, SCREEN_TOLERANCE, 0.0)
    hit = u < q_u - slack
    close = np.flatnonzero(~hit & (u < q_u + slack))
    if close.size:
        rows = uncertain[close]
        hit[close] = u[close] < _survival_ratio(z[rows], z_weather[rows])
    detected[uncertain] = hit
    return detected


def resolve_detection(
    setting: str | float, limit_power: float, spread_ln: float, frame_threshold: float
) -> Detection:
    """The rule a weather stage runs with.

    Args:
        setting: "sensor" (the profile's limit, conditional survival), "frame" (threshold
            calibrated to the frame) or a fixed P_min in reflectivity / m^2.
        limit_power, spread_ln: the sensor profile's P_lim and s.
        frame_threshold: the frame's weakest clear-air power (`beams.auto_threshold`).

    Raises:
        ConfigError: an unknown name or a threshold that is not a finite number > 0.
    """
    if isinstance(setting, str):
        if setting == "sensor":
            return Detection("sensor", float(limit_power), float(spread_ln))
        if setting == "frame":
            return Detection("frame", float(frame_threshold), 0.0)
        raise ConfigError(
            f"detection_threshold {setting!r}: expected one of {DETECTION_SETTINGS} or a "
            "fixed power > 0 in reflectivity / m^2 (e.g. 0.9 / 200**2, LISA's)."
        )
    value = float(setting)
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(
            f"detection_threshold = {setting!r}: a fixed threshold must be a finite power > 0 "
            f"in reflectivity / m^2, or one of {DETECTION_SETTINGS}."
        )
    return Detection("fixed", value, 0.0)
