"""Fog as single-scattering extinction plus a soft (volume) return per beam.

Re-implemented from the equations of Hahner et al. 2021 (arXiv 2108.05249; docs/physics.md §7)
and the lidar equation (docs/physics.md §9); no code or lookup table of the original is used.

Power convention (`lads.physics.beams`): received power is normalised so that a Lambertian
hard target of reflectivity rho (cos theta included) at range r gives, at its pulse peak,

    P_hard = rho * T^2(r) / r^2,        T^2(r) = exp(-2 alpha r).

Derivation of the matching fog (volume) return. With peak transmitted power P_T, pulse
shape w(t) (peak 1), receiver area A_R and efficiency eta, a Lambertian target returns
P_T eta A_R rho T^2 / (pi r^2) (docs/physics.md §9.2): dividing by P_T eta A_R / pi gives the
convention above. A slab [s, s + ds] of fog with lidar backscatter coefficient beta_pi
(1/(m sr), per steradian at 180 degrees) scatters P_T w beta_pi ds per steradian back to the
sensor; the aperture subtends A_R / s^2, so the slab adds P_T eta A_R w beta_pi xi(s) T^2(s)
ds / s^2, with xi the transmitter/receiver overlap. Light received at time 2r/c left the
sensor at time t after the pulse start from the slab at s = r - ct/2 (ds = c dt / 2), so in
the same normalisation

    P_soft(r; r0) = pi beta_pi * int_0^{2 tau_H} w(t) xi(s) T^2(s) / s^2 H(r0 - s) c dt/2,
    w(t) = sin^2(pi t / (2 tau_H)),     s = r - ct/2,

i.e. pi * beta_pi plays the role of a reflectivity per metre of fog; the Heaviside H keeps
only fog in front of the target at r0. This is docs/physics.md §7 with C_A P0 divided out, and it
needs beta_pi in the lidar convention (1/(m sr)); a radar-convention value is 4 pi larger.
Substituting u = r - s, L = c tau_H:

    P_soft(r; r0) = pi beta_pi * int_{max(r-L, 0)}^{min(r, r0)} sin^2(pi (r - s) / L) g(s) ds,
    g(s) = xi(s) exp(-2 alpha s) / s^2.

Its peak over r depends on (alpha, r0) only, and beta_pi is a factor, so one table per
alpha serves every beam. g decreases beyond R2, hence the peak range r*_inf of the r0 = inf
curve is <= R2 + L, and for r0 >= R2 + L the peak equals the r0 = inf peak exactly: the table
stops there. Range timing: a hard target's echo peaks at r0 + L/2 on this time axis and the
sensor is calibrated to report r0, so a fog peak at r* is reported at r* - L/2
(`FogParams.report_pulse_centre`; Hahner's "shifted" variant).

Model choices (see `FogParams`):
- extinction alpha = ln(20) / MOR (Koschmieder, 5 % contrast). MOR is defined in the
  visible; for fog drops (modal radius ~10 um, size parameter ~70 at 905 nm) Q_ext ~ 2 at
  both wavelengths, and the Mie ratio alpha(550 nm) / alpha(905 nm) over the default size
  distribution is 0.989 (derived), so alpha at 905 nm equals the visible one within ~1 %.
  Haze (sub-micron particles) would extinguish less at 905 nm; this module models fog only.
- backscatter "mie" (default): beta_pi = alpha / S with the lidar ratio S from Mie theory
  (miepython) over a modified-gamma advection-fog size distribution, S ~ 18 sr (derived);
  "hahner": beta_pi = 0.046 / MOR, i.e. S = ln(20) / 0.046 = 65 sr, 3.6x less backscatter.
- fog-return range noise: sigma = dR / sqrt(2 SNR) * kappa_pulse / kappa_fog, at most the
  echo's half-width 1 / sqrt(kappa_fog), and the reported range at most half a pulse beyond
  the target (the echo comes from fog in front of it). The
  peak-timing error of a shot-noise-limited peak detector scales as 1 / (sqrt(P) * |P''/P|);
  the sensor's dR / sqrt(2 SNR) holds for its own pulse (relative curvature
  kappa_pulse = 2 pi^2 / L^2), and the broader fog echo (smaller kappa_fog, tabulated) is
  timed less precisely in proportion.
- detection and returns: strongest / last return of two peaks (fog and target), compared
  without summing the waveforms (docs/physics.md §9.5), single scattering only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.physics.beams import (
    Beams,
    assemble,
    assemble_dual,
    auto_threshold,
    fixed_threshold_in_clear_air,
)
from lads.physics.detection import Detection, resolve_detection
from lads.physics.fog_echo import SoftReturnTable, soft_return_peak, soft_return_table
from lads.physics.fog_kernels import MODE_CODES, echo_lookup, fog_choices, fog_returns
from lads.physics.fog_optics import (
    backscatter_from_visibility,
    extinction_from_visibility,
    lidar_ratio_sr,
)
from lads.physics.result import Outcome, WeatherResult
from lads.sensors.profile import SensorProfile

# The echo table lives in fog_echo; its names stay importable from here.
__all__ = [
    "FogParams", "SoftReturnTable", "backscatter_from_visibility", "extinction_from_visibility",
    "lidar_ratio_sr", "simulate_fog", "soft_return_peak", "soft_return_table",
]  # fmt: skip

SPEED_OF_LIGHT_M_S = 299_792_458.0
MODES = ("strongest", "last", "dual")
BACKSCATTER_MODELS = ("mie", "hahner")
MIN_OUTPUT_RANGE_M = 1e-3
# One return per beam: (outcome codes uint8, range m, reflectivity), each (N,).
_Returns = tuple[npt.NDArray[np.uint8], npt.NDArray[np.float64], npt.NDArray[np.float64]]


@dataclass(frozen=True, slots=True)
class FogParams:
    """Parameters of the fog model, with defaults from Hahner et al. 2021 unless noted.

    Attributes:
        pulse_half_power_width_s: tau_H of the sin^2 pulse, s (its full width at half power;
            the pulse spans 2 tau_H); None takes the profile's `pulse_width_ns` (HDL-64E:
            4 ns, Velodyne); Hahner et al. use 20 ns.
        overlap_start_m: R1, range where the transmitter/receiver overlap xi starts, m;
            None takes the sensor profile's min_range_m (Hahner et al.: 0.9 for the HDL-64).
        overlap_full_m: R2 >= R1, range of full overlap, m; xi is linear from R1 to R2 (a
            step at R1 if equal); None takes the profile's overlap_full_m (Hahner: 1.0).
            The same overlap scales the particle returns of rain and snow, so one sensor
            property governs near-range clutter in every weather.
        backscatter_model: "mie" (beta_pi = alpha / S, S from Mie over the size
            distribution below) or "hahner" (beta_pi = hahner_backscatter_factor / MOR).
        hahner_backscatter_factor: beta_pi * MOR for "hahner", 1/sr (0.046; paper range
            0.023-0.092).
        droplet_modal_radius_um: r_c of the modified-gamma size distribution
            n(r) ~ r^a exp(-(a / g) (r / r_c)^g), um (10: strong advection fog, Rasshofer
            et al. 2011 via LISA `augment_avg`, docs/physics.md §1).
        droplet_shape_a: a of that distribution (3).
        droplet_shape_g: g of that distribution (1).
        refractive_index: real refractive index of water at the wavelength (1.328 at 905 nm;
            absorption there is negligible for 10 um drops).
        wavelength_nm: laser wavelength for the Mie lidar ratio, nm (905).
        report_pulse_centre: report a fog peak at r* - c tau_H / 2, as the sensor's hard-target
            range calibration does (True); False reports the raw pulse-start timing.
        table_step_m: range step of the soft-return table, m (0.01).
        detection_threshold: "sensor" (the profile's detection limit; targets survive with
            the conditional probability of docs/physics.md §9.7), "frame" (the frame's
            weakest clear-air return) or a fixed P_min in reflectivity / m^2
            (`lads.physics.detection.resolve_detection`).
    """

    pulse_half_power_width_s: float | None = None
    overlap_start_m: float | None = None
    overlap_full_m: float | None = None
    backscatter_model: str = "mie"
    hahner_backscatter_factor: float = 0.046
    droplet_modal_radius_um: float = 10.0
    droplet_shape_a: float = 3.0
    droplet_shape_g: float = 1.0
    refractive_index: float = 1.328
    wavelength_nm: float = 905.0
    report_pulse_centre: bool = True
    table_step_m: float = 0.01
    detection_threshold: float | str = "sensor"

    def __post_init__(self) -> None:
        positive = (
            "hahner_backscatter_factor",
            "droplet_modal_radius_um",
            "droplet_shape_a",
            "droplet_shape_g",
            "refractive_index",
            "wavelength_nm",
        )
        tau = self.pulse_half_power_width_s
        if tau is not None and not (math.isfinite(tau) and tau > 0):
            raise ConfigError(f"FogParams.pulse_half_power_width_s = {tau!r}; expected > 0 s.")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"FogParams.{name} = {value!r}; expected a finite value > 0.")
        r1, r2 = self.overlap_start_m, self.overlap_full_m
        if (r1 is not None and not 0 <= r1) or (r2 is not None and not r2 >= (r1 or 0.0)):
            raise ConfigError(
                f"FogParams overlap R1 = {self.overlap_start_m} m, R2 = {self.overlap_full_m} m; "
                "expected 0 <= overlap_start_m <= overlap_full_m."
            )
        if not 0 < self.table_step_m <= 0.1:
            raise ConfigError(
                f"FogParams.table_step_m = {self.table_step_m}; expected 0 < step <= 0.1 m "
                "(coarser steps misplace the fog peak)."
            )
        if self.backscatter_model not in BACKSCATTER_MODELS:
            raise ConfigError(
                f"FogParams.backscatter_model = {self.backscatter_model!r}; expected one of "
                f"{BACKSCATTER_MODELS}."
            )
        resolve_detection(self.detection_threshold, 1.0, 1.0, 1.0)  # raises if malformed

    @property
    def pulse_length_m(self) -> float:
        """L = c tau_H: range extent of the whole sin^2 pulse (c 2 tau_H / 2), m."""
        if self.pulse_half_power_width_s is None:
            raise ConfigError(
                "FogParams.pulse_half_power_width_s is None: call resolved_for(sensor) first."
            )
        return SPEED_OF_LIGHT_M_S * self.pulse_half_power_width_s

    def resolved_for(self, sensor: SensorProfile) -> FogParams:
        """Copy with every None overlap range and the pulse width taken from the profile."""
        r1 = sensor.min_range_m if self.overlap_start_m is None else self.overlap_start_m
        r2 = sensor.overlap_full_m if self.overlap_full_m is None else self.overlap_full_m
        tau = self.pulse_half_power_width_s
        tau = sensor.pulse_width_ns * 1e-9 if tau is None else tau
        return replace(
            self, overlap_start_m=r1, overlap_full_m=max(r1, r2), pulse_half_power_width_s=tau
        )


def simulate_fog(
    beams: Beams,
    sensor: SensorProfile,
    *,
    visibility_m: float,
    rng: np.random.Generator,
    mode: str = "strongest",
    params: FogParams | None = None,
) -> WeatherResult:
    """Apply homogeneous fog of a given visibility to one frame.

    Per active beam with target range r0 and reflectivity rho: hard-target power
    P_w = P_eff T^2(r0) and fog peak P_f (`soft_return_peak`); the target is detected by the
    rule of `lads.physics.detection` (default: the sensor's limit, conditioned on the clear-air
    detection), the fog echo if P_f >= P_min. strongest: fog return if it is detected and
    P_f > P_w, else the target if detected, else lost. last: the target if detected, else fog
    if detected, else lost. Kept targets (ATTENUATED) get intensity rho T^2 and extra range
    noise of variance sigma(SNR_w)^2 - sigma(SNR_clear)^2, sigma = dR / sqrt(2 SNR),
    SNR = P / P_min (LISA, docs/physics.md §4). Fog returns (PARTICLE) lie on the same ray at
    the reported peak range plus noise (module docstring), with intensity P_f r^2.
    Intensities are encoded once, by `assemble`.

    Args:
        beams: the prepared frame (`prepare_beams`), N beams.
        sensor: its profile (range_accuracy_m = dR, detection limit, intensity encoding).
        visibility_m: meteorological optical range (MOR), m; inf returns the input unchanged
            (under a fixed threshold, without the clear-air returns weaker than it).
        rng: source of the detection draws and range noise; the same state gives
            byte-identical output.
        mode: "strongest", "last" or "dual" (the strongest return and, where the fog echo is
            first, the target too).
        params: fog parameters (default `FogParams()`), detection rule included.

    Returns:
        WeatherResult with extinction_per_m = alpha and the P_min used.

    Raises:
        ConfigError: visibility_m NaN or <= 0, unknown mode, or a malformed threshold.
    """
    params = (FogParams() if params is None else params).resolved_for(sensor)
    if mode not in MODES:
        raise ConfigError(f"fog mode = {mode!r}; expected one of {MODES}.")
    alpha = extinction_from_visibility(visibility_m)
    detection = _frame_detection(beams, sensor, params)
    p_min = detection.threshold
    if alpha == 0.0 or beams.range_m.size == 0:
        clear = fixed_threshold_in_clear_air(beams, sensor, detection) if alpha == 0.0 else None
        return clear or _unchanged(beams, sensor, alpha, p_min)
    beta = backscatter_from_visibility(visibility_m, params)
    first, second = _beam_returns(beams, sensor, alpha, beta, params, detection, mode, rng)
    return assemble_dual(
        beams,
        sensor,
        first=first,
        second=second,
        extinction_per_m=alpha,
        detection_threshold=p_min,
    )


def _frame_detection(beams: Beams, sensor: SensorProfile, params: FogParams) -> Detection:
    """The frame's detection rule (`params.detection_threshold`; P_min in reflectivity / m^2)."""
    return resolve_detection(
        params.detection_threshold,
        sensor.detection.power,
        sensor.detection.spread_ln,
        auto_threshold(beams),
    )


def _beam_returns(
    beams: Beams,
    sensor: SensorProfile,
    alpha: float,
    beta: float,
    params: FogParams,
    detection: Detection,
    mode: str,
    rng: np.random.Generator,
) -> tuple[_Returns, _Returns]:
    """Per beam (N,) first and second returns (outcome, range m, reflectivity) in the fog."""
    n = beams.range_m.size
    idx = np.flatnonzero(beams.active)
    r0, rho = beams.range_m[idx], beams.reflectivity[idx]
    two_way_ln = -2.0 * alpha * r0
    t2 = np.exp(two_way_ln)
    target_ok, p_target = detection.targets_detected(
        beams.clear_power[idx], two_way_ln, np.ones(idx.size, dtype=bool), rng, t2
    )
    p_fog, reported, kappa = _fog_echoes(r0, alpha, beta, params)
    fog_ok = detection.faint_detected(p_fog, rng)
    length = params.pulse_length_m
    choice, counts = fog_choices(
        MODE_CODES[mode], target_ok, fog_ok, p_target, p_fog, r0, reported, length
    )
    noise = rng.standard_normal(int(counts[0]) + int(counts[1]))
    # Second echoes draw after the first returns' normals (none drawn where there are none).
    noise_second = rng.standard_normal(int(counts[2])) if counts[2] else np.zeros(0)
    codes1, range1, refl1, codes2, range2, refl2 = fog_returns(
        n,
        idx,
        choice,
        r0,
        rho,
        t2,
        p_target,
        detection.effective_power(rho / r0**2),
        p_fog,
        reported,
        kappa,
        noise,
        noise_second,
        _return_constants(sensor, detection.threshold, length),
    )
    return (codes1, range1, refl1), (codes2, range2, refl2)


def _unchanged(beams: Beams, sensor: SensorProfile, alpha: float, p_min: float) -> WeatherResult:
    """The frame as it is (clear air, or no beams), every beam KEPT."""
    n = beams.range_m.size
    return assemble(
        beams,
        sensor,
        outcome=np.full(n, Outcome.KEPT, dtype=np.uint8),
        range_m=np.zeros(n),
        reflectivity=np.zeros(n),
        extinction_per_m=alpha,
        detection_threshold=p_min,
    )


def _fog_echoes(
    r0: npt.NDArray[np.float64], alpha: float, beta: float, params: FogParams
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(A,) peak power, reported range (m) and relative peak curvature (1/m^2) of the fog echo
    in front of targets at r0 (m), in fog of extinction alpha (1/m) and backscatter beta
    (1/(m sr)) (`echo_lookup`). Raises ConfigError if params.overlap_start_m is unresolved."""
    table = soft_return_table(alpha, params)
    r1 = params.overlap_start_m
    if r1 is None:  # resolved_for(sensor) in simulate_fog set it
        raise ConfigError("simulate_fog: FogParams.overlap_start_m unresolved.")
    return echo_lookup(
        r0,
        table.target_range_m,
        table.peak_unit,
        table.peak_range_m,
        table.relative_curvature_per_m2,
        np.pi * beta,
        r1,
        0.5 * params.pulse_length_m if params.report_pulse_centre else 0.0,
    )


def _return_constants(
    sensor: SensorProfile, p_min: float, length_m: float
) -> npt.NDArray[np.float64]:
    """(6,) float64 constants of `fog_returns`: 0.5 dR^2 P_min (m^2), P_min, 2 pi^2 / L^2
    (1/m^2), dR (m), L / 2 (m) and the minimum output range (m), L the pulse length."""
    return np.array(
        [
            0.5 * sensor.range_accuracy_m**2 * p_min,
            p_min,
            2.0 * np.pi**2 / length_m**2,
            sensor.range_accuracy_m,
            0.5 * length_m,
            MIN_OUTPUT_RANGE_M,
        ]
    )
