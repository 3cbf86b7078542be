"""C6 class reflectance mismatch (a calibration error, not physics): + ln s_class, jointly
over the frequent classes and for each of them alone.
"""

from __future__ import annotations

import torch

from lads.diagnose.effects.base import RIDGE, Effect, EffectInfo, Offer, entry
from lads.diagnose.fit.design import Design

Tensor = torch.Tensor
INFOS = (
    EffectInfo("C6", "class_reflectance",
               "Class reflectance mismatch (a calibration error, not physics)",
               ("ln_scale_<class>",), ((-1.5, 1.5),), ("C3s", "C3r", "C7"), "intensity"),
)  # fmt: skip
C6 = INFOS[0]


def candidates(offer: Offer) -> list[Effect]:
    """With two or more frequent classes: the joint vector, then one class at a time."""
    d, frequent = offer.d, offer.frequent
    if len(frequent) < 2:
        return []
    # One class at a time as well: a mismatch confined to one class is diluted in the
    # joint vector, whose other entries fit object-level noise in the training groups
    # and give the held-out gain back (a shifted vegetation class went unnoticed).
    return [_class_scale(d, frequent)] + [
        one_class_scale(d, ci, d.class_names[ci]) for ci in frequent
    ]


def _class_scale(d: Design, frequent: list[int]) -> Effect:
    names = tuple(f"ln_scale_{d.class_names[ci]}" for ci in frequent)
    lookup = torch.full((len(d.class_names) + 1,), -1, dtype=torch.long)
    for j, ci in enumerate(frequent):
        lookup[ci] = j

    def term(th: Tensor, dd: Design) -> Tensor:
        idx = lookup[dd.class_index.clamp_min(-1)]  # -1 (unknown) reads the last slot: -1
        padded = torch.cat([th, torch.zeros(1, dtype=th.dtype)])
        return padded[idx]

    return entry(
        C6,
        names,
        [[0.0] * len(names)],
        d,
        scalar=[False] * len(names),
        ln_term=term,
        penalty=lambda th: RIDGE * (th**2).sum(),
    )


def one_class_scale(d: Design, ci: int, cname: str) -> Effect:
    """C6 on class index `ci` alone."""

    def term(th: Tensor, dd: Design) -> Tensor:
        return torch.where(dd.class_index == ci, th[0].expand_as(dd.cos), torch.zeros_like(dd.cos))

    return entry(
        C6,
        (f"ln_scale_{cname}",),
        [[0.0]],
        d,
        label=f"C6[{cname}]",
        class_index=ci,
        class_name=cname,
        ln_term=term,
    )
