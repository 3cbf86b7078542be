"""C9 intensity encoding: I = min(FS (I / FS)^gamma + offset, i_max) in stored units, a map
applied to the predicted intensity last. The clip i_max is read off the data, not fitted.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry
from lads.diagnose.fit.design import Design

Tensor = torch.Tensor
INFOS = (
    EffectInfo("C9", "intensity_encoding", "Encoding: power law, offset, quantization, clipping",
               ("gamma", "offset", "i_max"), ((0.4, 1.5), (-20.0, 20.0), (None, None)),
               ("C4o", "C2"), "intensity", encoded=("offset",)),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on every design."""
    return [_encoding(offer.d)]


def _encoding(d: Design) -> Effect:
    ln_fs = math.log(d.full_scale)

    def transfer(th: Tensor, dd: Design, mu: Tensor) -> Tensor:
        intensity = (torch.exp(mu) - dd.half_step).clamp_min(0.0)
        # The power law acts on reflectivity (intensity / full scale), so gamma is unitless.
        powered = torch.exp(th[0] * (torch.log(intensity + 1e-12) - ln_fs) + ln_fs)
        return torch.log((powered + th[1]).clamp_min(0.0) + dd.half_step)

    clip = d.real_clip

    def export(th: npt.NDArray[np.float64]) -> dict[str, Any]:
        out = {"gamma": float(th[0]), "offset": float(th[1])}
        if clip is not None:
            # The clip is read off the data (fit/from_table.py clip_level), not fitted: its rows are
            # censored in every model, so they cannot bias gamma.
            out["i_max"] = clip
        return out

    eff = entry(INFOS[0], ("gamma", "offset"), [[1.0, 0.0]], d, transfer=transfer, exporter=export)
    if clip is not None:
        eff.extra["ci_floor"] = {"i_max": 0.5 * d.step}
    return eff
