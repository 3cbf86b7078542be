"""C5 atmospheric attenuation: - 2 alpha R on the predicted ln I (two-way Beer-Lambert)."""

from __future__ import annotations

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry

INFOS = (
    EffectInfo("C5", "atmospheric_attenuation", "Atmospheric attenuation", ("alpha_per_m",),
               ((0.0, 0.5),), ("C1",), "both"),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on every design."""
    return [
        entry(
            INFOS[0],
            ("alpha_per_m",),
            [[0.001]],
            offer.d,
            ln_term=lambda th, dd: -2.0 * th[0] * dd.range_m,
        )
    ]
