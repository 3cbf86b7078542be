"""The physics reference of L_phy: the law fitted to each target's own training frames.

Until now L_phy pulled the generator towards k I_P, literature reflectances times a pooled
calibration k; a reference too dark for real KITTI (the synthetic frames dominated the
pooled k). Here each pair's reference is `lads.intensity.fitted_physics` fitted, per
material, to the occupied pixels of that pair's *target training* frames in the cache (the
same frames the identity term sees; validation and test frames are never cached), and
evaluated on any frame's raw input channels:

    ln(I_ref + f) = a_material + b1 ln R + b2 R / 10 m + s_l(ln R) + ln g(theta; sigma)
                    - 2 alpha R

(s_l: the range response of the pixel's laser, looked up by the row's elevation channel)

with f the target's z-space floor, so the reference lives in the generator's own output
space. Materials the target frames do not show take the pooled intercept. With
`law_groups: class` each class of the target's label set adds its own shrunk offset
(`lads.intensity.law_groups`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch

from lads.intensity import fitted_physics
from lads.intensity.cache import CachedFrame
from lads.intensity.features import ELEVATION_SCALE_DEG
from lads.intensity.law_groups import GroupedLaw, class_offsets


def fit_law(
    frames: Iterable[CachedFrame], floor: float, class_label_set: str | None = None
) -> GroupedLaw:
    """The law of one target, from its cached training frames (occupied pixels only): keyed
    by material, plus per-class offsets where `class_label_set` is given
    (`lads.intensity.law_groups`; the frames' class planes hold classes of that set)."""
    parts: dict[str, list[np.ndarray]] = {
        k: [] for k in ("mat", "cls", "r", "cos", "refl", "alpha", "elev")
    }
    for f in frames:
        if f.target is None:
            continue
        x = {n: f.plane(n) for n in ("mask", "ln_range", "cos_incidence", "material", "elevation")}
        occ = x["mask"] > 0
        parts["mat"].append(np.rint(x["material"][occ]).astype(np.int64) - 1)
        parts["cls"].append(f.class_plane[occ].astype(np.int64))
        parts["r"].append(np.exp(x["ln_range"][occ].astype(np.float64)))
        parts["cos"].append(x["cos_incidence"][occ].astype(np.float64))
        parts["refl"].append(f.target[occ].astype(np.float64))
        parts["alpha"].append(np.full(int(occ.sum()), f.extinction_per_m))
        parts["elev"].append(x["elevation"][occ].astype(np.float64) * ELEVATION_SCALE_DEG)
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    law = fitted_physics.fit(
        cat["mat"],
        cat["r"],
        cat["cos"],
        cat["refl"],
        floor=floor,
        extinction_per_m=cat["alpha"],
        elevation_deg=cat["elev"],
    )
    if class_label_set is None:
        return GroupedLaw(law)
    # The extinction as `TorchLaw` applies it: on the range clamped to the fitted support.
    r = np.clip(cat["r"], law.range_min_m, law.range_max_m)
    predicted = law.ln_predict(cat["mat"], r, cat["cos"], 0.0, cat["elev"])
    residual = np.log(cat["refl"] + floor) - (predicted - 2.0 * cat["alpha"] * r)
    return GroupedLaw(law, class_label_set, class_offsets(cat["cls"], residual, cat["r"]))


@dataclass
class TorchLaw:
    """A fitted law evaluated on raw input batches, (B, C, H, W) -> (B, 1, H, W) ln(I + f).

    The law is a fixed reference (no gradient flows into it), so it is evaluated by the
    numpy law itself on the batch's pixels: one implementation, numpy and torch agree."""

    grouped: GroupedLaw
    index: dict[str, int]  # channel name -> position in the raw batch

    @property
    def law(self) -> fitted_physics.FittedPhysics:
        return self.grouped.law

    @classmethod
    def of(
        cls, law: GroupedLaw | fitted_physics.FittedPhysics, channels: tuple[str, ...]
    ) -> TorchLaw:
        """The law (a bare fitted law: keyed by material) on batches of `channels`."""
        grouped = law if isinstance(law, GroupedLaw) else GroupedLaw(law)
        names = ("ln_range", "cos_incidence", "material", "elevation")
        return cls(grouped, {n: channels.index(n) for n in names})

    def ln_reference(
        self, raw: torch.Tensor, extinction: torch.Tensor, classes: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(B, 1, H, W) ln(I_ref + f) of a raw batch; `classes` (B, 1, H, W) class ids of
        the law's label set (-1 none; the cache writes them only for frames of that set)."""
        x = raw.detach().to("cpu", torch.float64).numpy()
        b, _, h, w = x.shape
        alpha = np.broadcast_to(
            extinction.detach().cpu().double().numpy()[:, None, None], (b, h, w)
        )
        pick = {n: x[:, i].ravel() for n, i in self.index.items()}
        # No material (0 in the channel, -1 here) takes the pooled intercept, as in numpy.
        material = np.rint(pick["material"]).astype(np.int64) - 1
        cls = None if classes is None else classes.detach().cpu().numpy().ravel()
        r = np.clip(np.exp(pick["ln_range"]), self.law.range_min_m, self.law.range_max_m)
        ln = self.grouped.ln_predict(
            material,
            r,
            pick["cos_incidence"],
            0.0,
            pick["elevation"] * ELEVATION_SCALE_DEG,
            cls,
            self.grouped.class_label_set,
        )
        ln = ln - 2.0 * alpha.ravel() * r
        return torch.from_numpy(ln.reshape(b, 1, h, w)).to(raw.device, raw.dtype)
