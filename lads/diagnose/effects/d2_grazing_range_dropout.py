"""D2 grazing-angle dropout: P(return) = Phi((cos theta - cos_c) / s_cos) where the normal is
well conditioned.
"""

from __future__ import annotations

import torch

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry, phi_log

INFOS = (
    EffectInfo("D2", "grazing_range_dropout", "Grazing-angle / range cutoff dropout",
               ("cos_c", "s_cos"), ((0.0, 0.9), (0.01, 0.5)), ("D1",), "dropout"),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on paired designs."""
    if not offer.d.paired:
        return []
    return [
        entry(
            INFOS[0],
            ("cos_c", "s_cos"),
            [[0.1, 0.05]],
            offer.d,
            log_survival=lambda th, dd: torch.where(
                dd.normal_ok, phi_log((dd.cos - th[0]) / th[1]), torch.zeros_like(dd.cos)
            ),
        )
    ]
