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

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import log_ndtr, ndtr

from lads.errors import ConfigError

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
        survival = target_survival(effective, two_way_ln, self.threshold, self.spread_ln)
        detected = active.copy()
        uncertain = np.flatnonzero(active & (survival < 1.0))
        if uncertain.size:
            detected[uncertain] = rng.random(uncertain.size) < survival[uncertain]
        return detected, power

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
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.log(effective_power / limit_power) / spread_ln
    z_weather = z + two_way_ln / spread_ln
    out = np.ones_like(z)
    doubtful = np.flatnonzero(np.isfinite(z) & (z_weather < CERTAIN_Z))
    if doubtful.size:
        zd, zw = z[doubtful], z_weather[doubtful]
        # Phi(z) >= 1/2 for z >= 0 (every target under the sensor rule, P_eff >= P_lim): the
        # plain ratio is exact there and cheaper; a z < 0 (another caller) takes the log form.
        plain = zd >= 0.0
        ratio = np.empty(doubtful.size)
        # Phi(z) is exactly 1 beyond CERTAIN_Z: the ratio is then Phi(z - d) itself.
        sure = zd >= CERTAIN_Z
        ratio[sure] = ndtr(zw[sure])
        part = plain & ~sure
        ratio[part] = ndtr(zw[part]) / ndtr(zd[part])
        ratio[~plain] = np.exp(log_ndtr(zw[~plain]) - log_ndtr(zd[~plain]))
        out[doubtful] = ratio
    return out


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
