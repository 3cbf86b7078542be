"""C3 incidence law (+ p_extra ln cos theta, or the Oren-Nayar roughness term), C3s specular
lobe and C3r retro-reflection, each confined to one class (+ ln(1 + k_s cos^m / cos); +
ln_gain - ln cos theta).
"""

from __future__ import annotations

import torch

from lads.diagnose.effects.base import MIN_CONFINED_ROWS, Effect, EffectInfo, Offer, entry
from lads.diagnose.fit.design import Design

Tensor = torch.Tensor
INFOS = (
    EffectInfo("C3", "incidence_law", "Incidence law", ("p_extra", "sigma_rad"),
               ((-1.0, 2.0), (0.0, 0.6)), ("C1",), "intensity"),
    EffectInfo("C3s", "specular_lobe", "Specular lobe (per class)", ("k_s", "m"),
               ((0.0, 5.0), (5.0, 300.0)), ("C6",), "intensity"),
    EffectInfo("C3r", "retro_reflection", "Retro-reflection (per class)", ("ln_gain",),
               ((0.0, 6.91),), ("C6", "C9"), "intensity"),
)  # fmt: skip
C3, C3S, C3R = INFOS


def candidates(offer: Offer) -> list[Effect]:
    """C3 as a cos power and as Oren-Nayar on every design; then, class by class, a specular
    lobe on clear-coated classes and retro-reflection on retro-reflective ones (their
    materials' `finish` in materials.yaml) with at least MIN_CONFINED_ROWS rows."""
    d = offer.d
    out = [
        entry(C3, ("p_extra",), [[0.0]], d, ln_term=lambda th, dd: th[0] * dd.ln_cos),
        _oren_nayar(d),
    ]
    for ci, cname in enumerate(d.class_names):
        if offer.counts[ci] < MIN_CONFINED_ROWS:
            continue
        if offer.has_role(ci, "clearcoat"):
            out.append(_specular(d, ci, cname))
        if offer.has_role(ci, "retroreflective"):
            out.append(_retro(d, ci, cname))
    return out


def _oren_nayar(d: Design) -> Effect:
    """C3 as the Oren-Nayar law seen monostatically, relative to Lambert.

    With incidence = exitance = theta and no azimuth difference, the rough-surface radiance
    over Lambert's is A + B sin(theta) tan(theta), A = 1 - 0.5 s^2 / (s^2 + 0.33), B = 0.45
    s^2 / (s^2 + 0.09), s the facet slope spread (rad). It rises towards grazing where cos^p
    only bends, so a rough ground fitted as cos^p leaves a range-like residual that ring
    offsets and attenuation then chase."""

    def term(th: Tensor, dd: Design) -> Tensor:
        s2 = th[0] ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        cos = dd.cos.clamp(0.05, 1.0)
        lobe = torch.log(a + b * (1.0 - cos**2) / cos)
        return torch.where(dd.normal_ok, lobe, torch.zeros_like(cos))

    # sigma = 0 is Lambert itself, so a fit there gains nothing and is rejected as at bound
    # like C5's alpha = 0.
    return entry(C3, ("sigma_rad",), [[0.2]], d, label="C3[oren_nayar]", ln_term=term)


def _specular(d: Design, ci: int, cname: str) -> Effect:
    def term(th: Tensor, dd: Design) -> Tensor:
        cos = dd.cos.clamp(0.05, 1.0)
        lobe = torch.log1p(th[0] * cos ** (th[1] - 1.0))
        return torch.where((dd.class_index == ci) & dd.normal_ok, lobe, torch.zeros_like(cos))

    return entry(
        C3S,
        ("k_s", "m"),
        [[1.0, 20.0], [1.0, 80.0]],
        d,
        label=f"C3s[{cname}]",
        class_index=ci,
        class_name=cname,
        ln_term=term,
    )


def _retro(d: Design, ci: int, cname: str) -> Effect:
    def term(th: Tensor, dd: Design) -> Tensor:
        return torch.where(dd.class_index == ci, th[0] - dd.ln_cos, torch.zeros_like(dd.ln_cos))

    return entry(
        C3R,
        ("ln_gain",),
        [[1.0]],
        d,
        label=f"C3r[{cname}]",
        class_index=ci,
        class_name=cname,
        ln_term=term,
    )
