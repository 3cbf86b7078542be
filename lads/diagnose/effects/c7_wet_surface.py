"""C7 wet surface on the road-like classes: + ln(1 - f) on the wet share, and no return
beyond the critical incidence theta_c there.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry, phi_log
from lads.diagnose.fit.design import Design

Tensor = torch.Tensor
INFOS = (
    EffectInfo("C7", "wet_surface", "Wet surface (per class)",
               ("f", "theta_c_deg", "cos_softness", "wet_share_<class>"),
               ((0.0, 0.95), (50.0, 89.0), (0.005, 0.2), (0.0, 1.0)), ("C6", "C3"), "both"),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """One candidate over the frequent road-like classes (materials.yaml `ground`), if any."""
    wet = [ci for ci in offer.frequent if offer.has_role(ci, "road_like")]
    return [_wet(offer.d, wet)] if wet else []


def _wet(d: Design, wet: list[int]) -> Effect:
    """C7 over the road-like classes, each with its own wet share w in [0, 1].

    A film darkens a wet surface by (1 - f) and, beyond theta_c, mirrors the beam away (no
    return); on a class wet in a share w of its area both act on that share. Pooling every
    road-like class at w = 1 wets the dry ones too (a dry car park that keeps its grazing
    returns refutes the cutoff), while one candidate per class splits one film over several
    forward steps, and a per-ring dropout that spans them all wins the first. Fitting w per
    class names the wet classes in one step; w at 0 or 1 is the expected answer, not a bound.
    """
    lookup = torch.zeros(len(d.class_names) + 1, dtype=torch.long)  # 0: not road-like
    for j, ci in enumerate(wet):
        lookup[ci] = j + 1
    names = tuple(f"wet_share_{d.class_names[ci]}" for ci in wet)

    def share(th: Tensor, dd: Design) -> Tensor:
        padded = torch.cat([torch.zeros(1, dtype=th.dtype), th[3:].clamp(1e-6, 1.0 - 1e-6)])
        return padded[lookup[dd.class_index.clamp_min(-1)]]

    def term(th: Tensor, dd: Design) -> Tensor:
        return torch.log1p(-th[0] * share(th, dd))

    def survival(th: Tensor, dd: Design) -> Tensor:
        # The cutoff is sharp in cos(theta); its fitted softness takes up the scatter of the
        # estimated normals, which a fixed narrow edge turned into huge per-row penalties.
        w = share(th, dd)
        z = (dd.cos - torch.cos(th[1] * math.pi / 180.0)) / th[2]
        kept = torch.logaddexp(torch.log1p(-w), torch.log(w) + phi_log(z))
        return torch.where(dd.normal_ok, kept, torch.zeros_like(kept))

    def export(th: npt.NDArray[np.float64]) -> dict[str, Any]:
        out: dict[str, Any] = {
            "f": float(th[0]),
            "theta_c_deg": float(th[1]),
            "cos_softness": float(th[2]),
        }
        out.update({n: float(v) for n, v in zip(names, th[3:], strict=True)})
        return out

    k = len(wet)
    eff = entry(
        INFOS[0],
        ("f", "theta_c_deg", "cos_softness", *names),
        [[0.3, 75.0, 0.03] + [0.5] * k, [0.5, 60.0, 0.03] + [0.9] * k],
        d,
        scalar=[True, True, False] + [False] * k,
        ln_term=term,
        log_survival=survival,
        exporter=export,
    )
    eff.extra["classes"] = [d.class_names[ci] for ci in wet]
    eff.extra["wet_share_names"] = names
    return eff
