"""The physics reference of L_phy: the law fitted to each target's own training frames.

Until now L_phy pulled the generator towards k I_P, literature reflectances times a pooled
calibration k; a reference too dark for real KITTI (the synthetic frames dominated the
pooled k). Here each pair's reference is `lads.intensity.fitted_physics` fitted, per
material, to the occupied pixels of that pair's *target training* frames in the cache (the
same frames the identity term sees; validation and test frames are never cached), and
evaluated on any frame's raw input channels:

    ln(I_ref + f) = a_material + b1 ln R + b2 R / 10 m + ln g(theta; sigma) - 2 alpha R

with f the target's z-space floor, so the reference lives in the generator's own output
space. Materials the target frames do not show take the pooled intercept.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch

from lads.intensity import fitted_physics
from lads.intensity.cache import CachedFrame
from lads.intensity.features import channel_names
from lads.physics.materials import material_names


def fit_law(frames: Iterable[CachedFrame], floor: float) -> fitted_physics.FittedPhysics:
    """The law of one target, from its cached training frames (occupied pixels only)."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("mat", "r", "cos", "refl", "alpha")}
    for f in frames:
        if f.target is None:
            continue
        names = channel_names(f.inputs.shape[0] != len(channel_names(False)))
        x = {n: f.inputs[names.index(n)] for n in ("mask", "ln_range", "cos_incidence",
                                                    "material")}  # fmt: skip
        occ = x["mask"] > 0
        parts["mat"].append(np.rint(x["material"][occ]).astype(np.int64) - 1)
        parts["r"].append(np.exp(x["ln_range"][occ].astype(np.float64)))
        parts["cos"].append(x["cos_incidence"][occ].astype(np.float64))
        parts["refl"].append(f.target[occ].astype(np.float64))
        parts["alpha"].append(np.full(int(occ.sum()), f.extinction_per_m))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    return fitted_physics.fit(cat["mat"], cat["r"], cat["cos"], cat["refl"], floor=floor,
                              extinction_per_m=cat["alpha"])  # fmt: skip


@dataclass
class TorchLaw:
    """A fitted law evaluated on raw input batches, (B, C, H, W) -> (B, 1, H, W) ln(I + f)."""

    intercepts: torch.Tensor  # (materials + 1,) by material index, pooled where unseen and last
    b1: float
    b2: float
    sigma_rad: float
    range_m: tuple[float, float]  # the fitted support; ranges are clamped into it
    index: dict[str, int]  # channel name -> position in the raw batch

    @classmethod
    def of(cls, law: fitted_physics.FittedPhysics, channels: tuple[str, ...]) -> TorchLaw:
        table = np.full(len(material_names()) + 1, law.pooled_intercept)
        for material, value in law.intercepts.items():
            if 0 <= material < len(table) - 1:
                table[material] = value
        names = ("ln_range", "cos_incidence", "material")
        return cls(torch.tensor(table, dtype=torch.float32), law.b1, law.b2, law.sigma_rad,
                   (law.range_min_m, law.range_max_m),
                   {n: channels.index(n) for n in names})  # fmt: skip

    def ln_reference(self, raw: torch.Tensor, extinction: torch.Tensor) -> torch.Tensor:
        r = torch.exp(raw[:, self.index["ln_range"]]).clamp(*self.range_m)
        ln_r = torch.log(r)
        cos = raw[:, self.index["cos_incidence"]].clamp(fitted_physics.COS_FLOOR, 1.0)
        a, b = fitted_physics.oren_nayar_coefficients(self.sigma_rad)
        material = raw[:, self.index["material"]].round().long() - 1
        # No material (-1) or one beyond the table: the pooled intercept, as in numpy.
        unknown = (material < 0) | (material >= len(self.intercepts) - 1)
        material = torch.where(unknown, len(self.intercepts) - 1, material)
        table = self.intercepts.to(raw.device)
        ln = (table[material] + self.b1 * ln_r + self.b2 * r / 10.0
              + torch.log(a * cos + b * (1.0 - cos**2))
              - 2.0 * extinction.to(raw.device)[:, None, None] * r)  # fmt: skip
        return ln[:, None]
