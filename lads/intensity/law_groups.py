"""A generator's fitted law with per-class offsets on top of its per-material intercepts.

A generator's law (`lads.intensity.law_reference`) is keyed by material, so it applies to
frames of any label set. Classes that share a material can read very differently on one
sensor (KITTI's parking and road are both asphalt; its "unlabeled" and "other-object" both
the unknown material). With `law_groups: class` the law keeps its material intercepts and
adds, for each class of the target's label set, an offset in ln(I + f):

    d_c = median over the class's fitted points of (ln(I + f) - law)  x  n_c / (n_c + n_0)

the least-absolute-deviation shift of that class given the material law, shrunk towards 0
by a prior worth n_0 = `fitted_physics.MIN_GROUP_POINTS` points (as many as a group needs for
an intercept of its own): a class seen a few times keeps its material's value, one never
seen (or seen only in the near field the law does not fit) exactly so. Frames labelled in
another label set (a synthetic source, a user's own labels) take no offset. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.intensity import fitted_physics
from lads.intensity.fitted_physics import FittedPhysics
from lads.sensors.conformity import NEAR_FIELD_M

CLASS_PRIOR_POINTS = fitted_physics.MIN_GROUP_POINTS


@dataclass(frozen=True)
class GroupedLaw:
    """A fitted law, and the offsets (ln units) of the classes of `class_label_set` (None:
    material intercepts only, the law of every model trained before class offsets)."""

    law: FittedPhysics
    class_label_set: str | None = None
    class_offsets: dict[int, float] = field(default_factory=dict)

    def ln_predict(
        self,
        material: npt.ArrayLike,
        range_m: npt.ArrayLike,
        cos_theta: npt.ArrayLike,
        extinction_per_m: float = 0.0,
        elevation_deg: npt.ArrayLike | None = None,
        classes: npt.ArrayLike | None = None,
        label_set: str | None = None,
    ) -> npt.NDArray[np.float64]:
        """(N,) ln(I + f): the material law (`FittedPhysics.ln_predict`) plus each point's
        class offset when `classes` ((N,) ids, -1 none) are of this law's label set."""
        ln = self.law.ln_predict(material, range_m, cos_theta, extinction_per_m, elevation_deg)
        # No offsets: the material law's own array, not a copy plus zero.
        return ln + self.offsets(classes, label_set) if self.class_offsets else ln

    def offsets(
        self, classes: npt.ArrayLike | None, label_set: str | None
    ) -> npt.NDArray[np.float64] | float:
        """(N,) the class offset of each point (0 for classes without one), or 0.0 when the
        classes are not of this law's label set."""
        if not self._applies(classes, label_set):
            return 0.0
        c = np.asarray(classes, dtype=np.int64)
        ids = np.fromiter(self.class_offsets, dtype=np.int64, count=len(self.class_offsets))
        table = np.zeros(int(max(ids.max(), c.max(initial=0))) + 1)
        table[ids] = list(self.class_offsets.values())
        return np.where(c >= 0, table[np.maximum(c, 0)], 0.0)

    def _applies(self, classes: npt.ArrayLike | None, label_set: str | None) -> bool:
        return (
            bool(self.class_offsets)
            and classes is not None
            and label_set is not None
            and label_set == self.class_label_set
        )

    def to_json(self) -> dict[str, Any]:
        out = self.law.to_json()
        if self.class_label_set is not None:
            out["class_offsets"] = {
                "label_set": self.class_label_set,
                "ln_offsets": {str(k): v for k, v in sorted(self.class_offsets.items())},
            }
        return out

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> GroupedLaw:
        groups = raw.get("class_offsets")
        if groups is None:
            return cls(FittedPhysics.from_json(raw))
        offsets = {int(k): float(v) for k, v in groups["ln_offsets"].items()}
        return cls(FittedPhysics.from_json(raw), str(groups["label_set"]), offsets)


def class_offsets(
    classes: npt.NDArray[np.int64],
    ln_residual: npt.NDArray[np.float64],
    range_m: npt.NDArray[np.float64],
) -> dict[int, float]:
    """{class: d_c} (module doc) from the training points' classes (-1 none), residuals
    ln(I + f) - law and ranges; points in the near field, which the law does not fit, are
    left out."""
    fitted = (classes >= 0) & (range_m > NEAR_FIELD_M) & np.isfinite(ln_residual)
    out: dict[int, float] = {}
    for c in np.unique(classes[fitted]):
        r = ln_residual[fitted & (classes == c)]
        out[int(c)] = float(np.median(r) * len(r) / (len(r) + CLASS_PRIOR_POINTS))
    return out
