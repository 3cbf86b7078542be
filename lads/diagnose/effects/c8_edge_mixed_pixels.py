"""C8 mixed pixels at edges: + ln(1 - a exp(-e / e0)), e the distance to an edge in beams."""

from __future__ import annotations

import torch

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry
from lads.diagnose.fit.design import Design

Tensor = torch.Tensor
INFOS = (
    EffectInfo("C8", "edge_mixed_pixels", "Mixed pixels at edges", ("a", "e0_beams"),
               ((0.0, 0.9), (0.5, 3.0)), (), "intensity"),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on every design."""
    return [
        entry(
            INFOS[0],
            ("a", "e0_beams"),
            [[0.3, 1.0]],
            offer.d,
            ln_term=lambda th, dd: torch.log1p(-th[0] * edge_cover(dd, th[1])),
        )
    ]


def edge_cover(d: Design, e0: Tensor) -> Tensor:
    """(N,) E[exp(-e / e0)] with the edge distance e uniform on edge_beams +- span / 2
    (clipped at 0): on a thinned or gappy scan the edge lies somewhere in the gap, and
    exp(-e / e0) at the gap's midpoint understates how close some of those returns are."""
    lo = (d.edge_beams - 0.5 * d.edge_span_beams).clamp_min(0.0)
    hi = d.edge_beams + 0.5 * d.edge_span_beams
    width = hi - lo
    wide = width > 1e-6
    mean = e0 * (torch.exp(-lo / e0) - torch.exp(-hi / e0)) / torch.where(wide, width, 1.0)
    return torch.where(wide, mean, torch.exp(-d.edge_beams / e0))
