"""D3 dead or weak channel: P(return) times (1 - p_drop) on each ring; reported with the
rings whose p_drop is above 0.1.
"""

from __future__ import annotations

import numpy as np
import torch

from lads.diagnose.effects.base import RIDGE, Effect, EffectInfo, Offer, entry, ring_vector

INFOS = (
    EffectInfo("D3", "dead_channel", "Dead or weak channel", ("rings", "p_drop", "p_drop_by_ring"),
               ((None, None), (0.0, 0.999), (0.0, 0.999)), ("C4",), "dropout"),
)  # fmt: skip
REPORTED_P_DROP = 0.1  # a ring is named as weak above this drop probability


def candidates(offer: Offer) -> list[Effect]:
    """One candidate (a drop probability per ring) on paired designs."""
    d = offer.d
    if not d.paired:
        return []
    n = d.n_rings
    return [
        entry(
            INFOS[0],
            ring_vector("p_drop_by_ring", n),
            [[0.0] * n],
            d,
            scalar=[False] * n,
            log_survival=lambda th, dd: torch.log1p(-th[dd.ring]),
            penalty=lambda th: RIDGE * th.sum(),
            exporter=lambda th: {
                "rings": [int(k) for k in np.flatnonzero(th > REPORTED_P_DROP)],
                "p_drop": [float(v) for v in th[th > REPORTED_P_DROP]],
                "p_drop_by_ring": [float(v) for v in th],
            },
        )
    ]
