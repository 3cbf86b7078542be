"""C1 range exponent (or an internal range compensation): - delta_n ln(R / R_ref).

R_ref is the design's geometric mean range, so the exponent does not trade with the global
gain.
"""

from __future__ import annotations

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry

INFOS = (
    EffectInfo("C1", "range_exponent", "Range exponent / internal range compensation",
               ("delta_n",), ((-2.5, 2.0),), ("C5", "C2", "C3", "C4"), "intensity"),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on every design."""
    d = offer.d
    ln_r_ref = float(d.ln_range.mean())
    return [
        entry(
            INFOS[0],
            ("delta_n",),
            [[0.0]],
            d,
            ln_term=lambda th, dd: -th[0] * (dd.ln_range - ln_r_ref),
        )
    ]
