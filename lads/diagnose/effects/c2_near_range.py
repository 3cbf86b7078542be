"""C2 near-range overlap (or saturation): - ln(1 + (r0_m / R)^k); C2v Velodyne per-laser
focal compensation (catalogued, not offered yet: no term).
"""

from __future__ import annotations

import torch

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry

INFOS = (
    EffectInfo("C2", "near_range_overlap", "Near-range optics/overlap (or saturation)",
               ("r0_m", "k"), ((0.5, 12.0), (1.0, 8.0)), ("C1", "C9"), "intensity"),
    EffectInfo("C2v", "velodyne_focal_compensation", "Velodyne per-laser focal compensation",
               ("focal_m_by_ring", "slope_by_ring"), ((5.0, 30.0), (0.0, 3.0)), ("C4",),
               "intensity", offered=False),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """C2 on every design, from three overlap distances."""
    return [
        entry(
            INFOS[0],
            ("r0_m", "k"),
            [[1.5, 3.0], [3.0, 3.0], [6.0, 3.0]],
            offer.d,
            ln_term=lambda th, dd: -torch.log1p((th[0] / dd.range_m.clamp_min(0.1)) ** th[1]),
        )
    ]
