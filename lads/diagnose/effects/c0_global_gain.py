"""C0 global gain: + ln_gain on every predicted ln I.

Part of every model's baseline (fit/likelihood.py), so it is never offered as a candidate.
"""

from __future__ import annotations

from lads.diagnose.effects.base import Effect, EffectInfo, Offer

INFOS = (
    EffectInfo("C0", "global_gain", "Global gain", ("ln_gain",), ((None, None),), (),
               "intensity", offered=False),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """None: the global gain is in the baseline."""
    return []
