"""The named effect catalogue of `lads diagnose` (docs/diagnose.md §1 and §5.3), assembled
from one module per effect family, listed in FAMILIES.

IDs and keys are stable names: they are never renamed or reused, and a new effect gets a new
ID. Each family module declares its entries (`INFOS`: parameters with units, bounds,
confounds) and its terms (`candidates`); the fitter, the report and the benchmark generator
all read the entries here. A parameter's value in report.json is a number, or a list of
numbers (one per ring) for the per-ring effects.

Parametrisation (what report.json's `params` mean): ID key: parameters -> term of
ln I_real - ln I_sim, or of the return probability. `mu` is the predicted ln I_real (ln of
the stored intensity plus half a step).
    C0  global_gain: ln_gain -> + ln_gain (part of every baseline)
    C1  range_exponent: delta_n -> - delta_n ln(R / 1 m)
    C2  near_range_overlap: r0_m, k -> - ln(1 + (r0_m / R)^k)
    C2v velodyne_focal_compensation: catalogued, not offered yet
    C3  incidence_law: p_extra -> + p_extra ln cos(theta); or (C3[oren_nayar]) sigma_rad ->
        the Oren-Nayar roughness term
    C3s specular_lobe (one class): k_s, m -> + ln(1 + k_s cos^m / cos)
    C3r retro_reflection (one class): ln_gain -> + ln_gain - ln cos(theta)
    C4  ring_gain: ln_gain_by_ring (sum 0) -> + ln g_ring
    C4o ring_offset: offset_by_ring (stored units) -> I + b_ring, before the ln
    C5  atmospheric_attenuation: alpha_per_m -> - 2 alpha R
    C6  class_reflectance: ln_scale_<class> per class -> + ln s_class
    C7  wet_surface (road-like classes): f, theta_c_deg, cos_softness, wet_share_<class> ->
        + ln(1 - f); no return beyond theta_c
    C8  edge_mixed_pixels: a, e0_beams -> + ln(1 - a exp(-e / e0)), e = beams to an edge
    C9  intensity_encoding: gamma, offset, i_max (stored units) -> I = min(FS (I / FS)^gamma
        + offset, i_max); the clip i_max is read off the data, not fitted
    C10 scan_auto_gain: beta -> - beta (mean ln I_sim of the scan - mean over scans)
    C11 azimuth_blockage: start_deg, width_deg, a, drop_fraction -> + ln(1 - a) in the
        sector, return probability times (1 - drop_fraction) there
    D1  detection_threshold: ln_tau, s, latent_share -> P(ret) = Phi((mu - ln_tau) / s)
    D2  grazing_range_dropout: cos_c, s_cos -> P(ret) = Phi((cos - cos_c) / s_cos)
    D3  dead_channel: p_drop_by_ring -> P(ret) (1 - p_drop) on rings
"""

from __future__ import annotations

from types import ModuleType

import numpy as np
import numpy.typing as npt

from lads.diagnose.effects import (
    c0_global_gain,
    c1_range_exponent,
    c2_near_range,
    c3_incidence,
    c4_rings,
    c5_atmospheric_attenuation,
    c6_class_reflectance,
    c7_wet_surface,
    c8_edge_mixed_pixels,
    c9_intensity_encoding,
    c10_scan_auto_gain,
    c11_azimuth_blockage,
    d1_detection_threshold,
    d2_grazing_range_dropout,
    d3_dead_channel,
)
from lads.diagnose.effects.base import Effect, EffectInfo, Offer
from lads.diagnose.fit.design import Design

# Every effect family, in the order their candidates are offered (the order of a selection's
# trace and of ties between equal candidates).
FAMILIES: tuple[ModuleType, ...] = (
    c0_global_gain,
    c1_range_exponent,
    c2_near_range,
    c3_incidence,
    c4_rings,
    c5_atmospheric_attenuation,
    c6_class_reflectance,
    c7_wet_surface,
    c8_edge_mixed_pixels,
    c9_intensity_encoding,
    c10_scan_auto_gain,
    c11_azimuth_blockage,
    d1_detection_threshold,
    d2_grazing_range_dropout,
    d3_dead_channel,
)

CATALOGUE: dict[str, EffectInfo] = {info.id: info for m in FAMILIES for info in m.INFOS}
BY_KEY: dict[str, EffectInfo] = {e.key: e for e in CATALOGUE.values()}


def effect(id_or_key: str) -> EffectInfo:
    """The catalogue entry for an ID ("C5") or key ("atmospheric_attenuation").

    Raises:
        KeyError: neither an ID nor a key of the catalogue.
    """
    if id_or_key in CATALOGUE:
        return CATALOGUE[id_or_key]
    return BY_KEY[id_or_key]


def candidates(d: Design, *, train_rows: npt.NDArray[np.int64] | None = None) -> list[Effect]:
    """The catalogue effects the design can inform (C0 is part of the baseline).

    Rules (docs/diagnose.md §5.3 "Needs"): class-confined effects only for labelled classes with
    enough rows; C10 only with enough scans; dropout effects only for paired designs. Effects
    whose shape is chosen from the data look at `train_rows` only.
    """
    offer = Offer.of(d, train_rows)
    return [eff for family in FAMILIES for eff in family.candidates(offer)]
