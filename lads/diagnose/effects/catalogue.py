"""The named effect catalogue of `lads diagnose` (docs/diagnose.md §1 and §5.3).

IDs and keys are stable names: they are never renamed or reused, and a new effect gets a new
ID. Parameter names carry their units; a parameter's value in report.json is a number, or a
list of numbers (one per ring) for the per-ring effects. This module is metadata only; the
terms live in `lads.diagnose.effects.terms`.

Parametrisation (what report.json's `params` mean): ID key: parameters -> term of
ln I_real - ln I_sim, or of the return probability.
    C0  global_gain: ln_gain -> + ln_gain
    C1  range_exponent: delta_n -> - delta_n ln(R / 1 m)
    C2  near_range_overlap: r0_m, k -> - ln(1 + (r0_m / R)^k)
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
        + offset, i_max); the fitter does not estimate the clip i_max yet
    C10 scan_auto_gain: beta -> - beta (mean ln I_sim of the scan - mean over scans)
    C11 azimuth_blockage: start_deg, width_deg, a, drop_fraction -> + ln(1 - a) in the
        sector, return probability times (1 - drop_fraction) there (start_deg is fitted on
        -360..720 so the sector can wrap, and reported modulo 360)
    D1  detection_threshold: ln_tau, s (latent_share) -> P(ret) = Phi((mu - ln_tau) / s);
        latent_share in [0, 1] is the share of the real value's deviation from mu that the
        detector also sees (1: the returned y itself is censored, Tobit)
    D2  grazing_range_dropout: cos_c, s_cos -> P(ret) = Phi((cos - cos_c) / s_cos)
    D3  dead_channel: p_drop_by_ring (reported with the rings and p_drop above 0.1) ->
        P(ret) (1 - p_drop) on rings
`mu` is the predicted ln I_real (ln of the stored intensity plus half a step).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class EffectInfo:
    """One catalogue entry.

    Attributes:
        id: stable ID, e.g. "C5".
        key: stable snake_case key, e.g. "atmospheric_attenuation".
        name: the name printed in reports.
        params: parameter names, units in the names.
        bounds: (low, high) per parameter as the fitter bounds it (None: free, or set from
            the data: the encoding offsets of C4o and C9 are scaled to the encoding);
            per-ring and per-class parameters share one bound. Checked against the fitted
            candidates by tests/unit/test_diagnose_catalogue.py.
        confounds: IDs of effects it is known to be confused with (docs/diagnose.md §5.3).
        kind: "intensity", "dropout" or "both".
    """

    id: str
    key: str
    name: str
    params: tuple[str, ...]
    bounds: tuple[tuple[float | None, float | None], ...]
    confounds: tuple[str, ...]
    kind: str


CATALOGUE: dict[str, EffectInfo] = {
    e.id: e
    for e in (
        EffectInfo("C0", "global_gain", "Global gain", ("ln_gain",), ((None, None),), (),
                   "intensity"),
        EffectInfo("C1", "range_exponent", "Range exponent / internal range compensation",
                   ("delta_n",), ((-2.5, 2.0),), ("C5", "C2", "C3", "C4"), "intensity"),
        EffectInfo("C2", "near_range_overlap", "Near-range optics/overlap (or saturation)",
                   ("r0_m", "k"), ((0.5, 12.0), (1.0, 8.0)), ("C1", "C9"), "intensity"),
        EffectInfo("C2v", "velodyne_focal_compensation", "Velodyne per-laser focal compensation",
                   ("focal_m_by_ring", "slope_by_ring"), ((5.0, 30.0), (0.0, 3.0)), ("C4",),
                   "intensity"),
        EffectInfo("C3", "incidence_law", "Incidence law", ("p_extra", "sigma_rad"),
                   ((-1.0, 2.0), (0.0, 0.6)), ("C1",), "intensity"),
        EffectInfo("C3s", "specular_lobe", "Specular lobe (per class)", ("k_s", "m"),
                   ((0.0, 5.0), (5.0, 300.0)), ("C6",), "intensity"),
        EffectInfo("C3r", "retro_reflection", "Retro-reflection (per class)", ("ln_gain",),
                   ((0.0, 6.91),), ("C6", "C9"), "intensity"),
        EffectInfo("C4", "ring_gain", "Per-ring gain", ("ln_gain_by_ring",), ((-1.0, 1.0),),
                   ("C1", "C2"), "intensity"),
        EffectInfo("C4o", "ring_offset", "Per-ring offset (encoded units)", ("offset_by_ring",),
                   ((-20.0, 20.0),), ("C9",), "intensity"),
        EffectInfo("C5", "atmospheric_attenuation", "Atmospheric attenuation", ("alpha_per_m",),
                   ((0.0, 0.5),), ("C1",), "both"),
        EffectInfo("C6", "class_reflectance",
                   "Class reflectance mismatch (a calibration error, not physics)",
                   ("ln_scale_<class>",), ((-1.5, 1.5),), ("C3s", "C3r", "C7"), "intensity"),
        EffectInfo("C7", "wet_surface", "Wet surface (per class)",
                   ("f", "theta_c_deg", "cos_softness", "wet_share_<class>"),
                   ((0.0, 0.95), (50.0, 89.0), (0.005, 0.2), (0.0, 1.0)), ("C6", "C3"), "both"),
        EffectInfo("C8", "edge_mixed_pixels", "Mixed pixels at edges", ("a", "e0_beams"),
                   ((0.0, 0.9), (0.5, 3.0)), (), "intensity"),
        EffectInfo("C9", "intensity_encoding",
                   "Encoding: power law, offset, quantization, clipping",
                   ("gamma", "offset", "i_max"), ((0.4, 1.5), (-20.0, 20.0), (None, None)),
                   ("C4o", "C2"), "intensity"),
        EffectInfo("C10", "scan_auto_gain", "Scan-level AGC", ("beta",), ((0.0, 1.5),), ("C0",),
                   "intensity"),
        EffectInfo("C11", "azimuth_blockage", "Azimuth-sector blockage / window contamination",
                   ("start_deg", "width_deg", "a", "drop_fraction"),
                   ((-360.0, 720.0), (2.0, 90.0), (0.0, 0.95), (0.0, 0.95)),
                   (), "both"),
        EffectInfo("D1", "detection_threshold", "Detection threshold (joint with intensity)",
                   ("ln_tau", "s", "latent_share"), ((-30.0, 10.0), (0.05, 3.0), (0.0, 1.0)),
                   ("D2",), "dropout"),
        EffectInfo("D2", "grazing_range_dropout", "Grazing-angle / range cutoff dropout",
                   ("cos_c", "s_cos"), ((0.0, 0.9), (0.01, 0.5)), ("D1",), "dropout"),
        EffectInfo("D3", "dead_channel", "Dead or weak channel",
                   ("rings", "p_drop", "p_drop_by_ring"),
                   ((None, None), (0.0, 0.999), (0.0, 0.999)), ("C4",), "dropout"),
    )
}  # fmt: skip

BY_KEY: dict[str, EffectInfo] = {e.key: e for e in CATALOGUE.values()}


def effect(id_or_key: str) -> EffectInfo:
    """The catalogue entry for an ID ("C5") or key ("atmospheric_attenuation").

    Raises:
        KeyError: neither an ID nor a key of the catalogue.
    """
    if id_or_key in CATALOGUE:
        return CATALOGUE[id_or_key]
    return BY_KEY[id_or_key]
