"""A parametric physics model of a sensor's intensity, fitted from its own real frames.

    ln(I + f) = a_g + b1 ln(R / 1 m) + b2 R / 10 m + ln g(theta; sigma) - 2 alpha R

with I the reflectivity (encoded / full scale), f the encoding's detection floor, a_g the
log reflectance (times the sensor's gain) of group g (a semantic class, or a material),
b1 and b2 a range law (b1 = -2 is the bare radar equation; real sensors compensate range,
`lads diagnose` finds the remission of KITTI rising with range), and g the Oren-Nayar
diffuse law in the backscatter geometry (docs/physics.md §10.1): viewing and lighting
directions coincide, so with A = 1 - 0.5 s/(s + 0.33), B = 0.45 s/(s + 0.09), s = sigma^2,

    g(theta) = A cos(theta) + B sin^2(theta)

(sigma = 0 is Lambert's cos theta; rough surfaces stay bright towards grazing incidence).
alpha is the frame's known extinction (weather), not fitted.

Fitted on training frames only: for each sigma of a grid, the linear parameters by
iteratively reweighted least squares on |residual| (a least-absolute-deviation fit, whose
prediction is the conditional median: the MAE-optimal point value); the sigma with the
smallest mean absolute residual wins. Groups seen fewer than MIN_GROUP_POINTS times take
the pooled intercept. Only returns beyond the near field (`NEAR_FIELD_M`, where ego-body
and mounting-offset returns sit) are fitted, and the law is evaluated with the range clamped
to the fitted support [range_min_m, range_max_m]: a power law in R extrapolated to a 0.1 m
ego return would be several e-folds off. Pure numpy, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.sensors.conformity import NEAR_FIELD_M

SIGMA_GRID_RAD: tuple[float, ...] = tuple(np.round(np.linspace(0.0, 1.2, 13), 3))
MIN_GROUP_POINTS = 50
IRLS_STEPS = 12
IRLS_FLOOR = 1e-3  # |residual| below which a point's weight stops growing
COS_FLOOR = 1e-3
MAX_FIT_POINTS = 400_000  # an even subsample beyond this: the fit has ~40 parameters


def oren_nayar(cos_theta: npt.ArrayLike, sigma_rad: float) -> npt.NDArray[np.float64]:
    """Backscatter Oren-Nayar factor g(theta) = A cos + B sin^2, (N,) float64 in [0, 1]."""
    c = np.clip(np.asarray(cos_theta, dtype=np.float64), COS_FLOOR, 1.0)
    a, b = oren_nayar_coefficients(sigma_rad)
    return a * c + b * (1.0 - c**2)


def oren_nayar_coefficients(sigma_rad: float) -> tuple[float, float]:
    """(A, B) of g(theta) = A cos + B sin^2 for roughness sigma (rad)."""
    s = sigma_rad**2
    return 1.0 - 0.5 * s / (s + 0.33), 0.45 * s / (s + 0.09)


@dataclass(frozen=True)
class FittedPhysics:
    """The fitted law. Attributes as in the module doc; `intercepts` maps group -> a_g."""

    intercepts: dict[int, float]
    pooled_intercept: float
    b1: float
    b2: float
    sigma_rad: float
    floor: float
    range_min_m: float = 1e-3
    range_max_m: float = float("inf")
    mae_log: float = 0.0
    points: int = 0
    counts: dict[int, int] = field(default_factory=dict)

    def ln_predict(
        self, group: npt.ArrayLike, range_m: npt.ArrayLike, cos_theta: npt.ArrayLike,
        extinction_per_m: float = 0.0,
    ) -> npt.NDArray[np.float64]:  # fmt: skip
        """(N,) predicted ln(I + floor) of points of the given groups, ranges and cosines."""
        r = np.clip(np.asarray(range_m, dtype=np.float64), self.range_min_m, self.range_max_m)
        g = np.asarray(group, dtype=np.int64)
        a = self.intercept_of(g)
        incidence = np.log(oren_nayar(cos_theta, self.sigma_rad))
        return a + self.b1 * np.log(r) + self.b2 * r / 10.0 + incidence - 2.0 * extinction_per_m * r

    def intercept_of(self, group: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
        """(N,) a_g of each point's group; the pooled intercept for groups not fitted."""
        if not self.intercepts:
            return np.full(len(group), self.pooled_intercept)
        keys = np.fromiter(self.intercepts, dtype=np.int64)
        low = int(keys.min())  # group ids may be negative (an unlabelled class)
        table = np.full(int(keys.max()) - low + 1, self.pooled_intercept)
        table[keys - low] = list(self.intercepts.values())
        known = (group >= low) & (group < low + len(table))
        return np.where(known, table[np.where(known, group - low, 0)], self.pooled_intercept)

    def predict(
        self, group: Any, range_m: Any, cos_theta: Any, extinction_per_m: float = 0.0
    ) -> npt.NDArray[np.float64]:
        """(N,) predicted reflectivity (>= 0)."""
        ln = self.ln_predict(group, range_m, cos_theta, extinction_per_m)
        return np.maximum(np.exp(ln) - self.floor, 0.0)

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> FittedPhysics:
        """Read back `to_json` (the fitted law, without its training tallies)."""
        return cls(
            intercepts={int(k): float(v) for k, v in raw["intercepts"].items()},
            pooled_intercept=float(raw["pooled_intercept"]), b1=float(raw["b1_ln_range"]),
            b2=float(raw["b2_per_10m"]), sigma_rad=float(raw["sigma_rad"]),
            floor=float(raw["floor"]), range_min_m=float(raw["range_min_m"]),
            range_max_m=float(raw["range_max_m"]),
        )  # fmt: skip

    def to_json(self) -> dict[str, Any]:
        return {"b1_ln_range": self.b1, "b2_per_10m": self.b2, "sigma_rad": self.sigma_rad,
                "pooled_intercept": self.pooled_intercept, "floor": self.floor,
                "range_min_m": self.range_min_m, "range_max_m": self.range_max_m,
                "intercepts": {str(k): v for k, v in sorted(self.intercepts.items())},
                "mae_log_train": self.mae_log, "points": self.points}  # fmt: skip


def fit(
    group: npt.ArrayLike, range_m: npt.ArrayLike, cos_theta: npt.ArrayLike,
    reflectivity: npt.ArrayLike, *, floor: float, extinction_per_m: npt.ArrayLike | float = 0.0,
) -> FittedPhysics:  # fmt: skip
    """Fit the law to (N,) training points: group ids, ranges (m), cosines, reflectivity.

    Raises:
        ValueError: fewer than MIN_GROUP_POINTS points.
    """
    g = np.asarray(group, dtype=np.int64)
    r = np.maximum(np.asarray(range_m, dtype=np.float64), 1e-3)
    c = np.asarray(cos_theta, dtype=np.float64)
    alpha = np.broadcast_to(np.asarray(extinction_per_m, dtype=np.float64), r.shape)
    y = np.log(np.asarray(reflectivity, dtype=np.float64) + floor) + 2.0 * alpha * r
    far = r >= NEAR_FIELD_M
    if np.count_nonzero(far) >= MIN_GROUP_POINTS:  # else (toy data) every point is fitted
        g, r, c, y = g[far], r[far], c[far], y[far]
    if len(y) < MIN_GROUP_POINTS:
        raise ValueError(f"{len(y)} training points; the law needs at least {MIN_GROUP_POINTS}.")
    if len(y) > MAX_FIT_POINTS:
        keep = np.linspace(0, len(y) - 1, MAX_FIT_POINTS).round().astype(np.int64)
        g, r, c, y = g[keep], r[keep], c[keep], y[keep]
    keys, counts = np.unique(g, return_counts=True)
    kept = keys[counts >= MIN_GROUP_POINTS]
    column = np.searchsorted(kept, g)
    member = (column < len(kept)) & (kept[np.minimum(column, len(kept) - 1)] == g)
    design = np.zeros((len(y), len(kept) + 3))
    design[np.flatnonzero(member), column[member]] = 1.0
    design[~member, len(kept)] = 1.0  # the pooled intercept of rare groups
    design[:, -2], design[:, -1] = np.log(r), r / 10.0
    best = None
    for sigma in SIGMA_GRID_RAD:
        target = y - np.log(oren_nayar(c, sigma))
        beta, loss = _lad(design, target)
        if best is None or loss < best[2]:
            best = (sigma, beta, loss)
    sigma, beta, loss = best  # type: ignore[misc]
    pooled = float(beta[len(kept)]) if (~member).any() else float(np.median(beta[: len(kept)]))
    return FittedPhysics(
        intercepts={int(k): float(v) for k, v in zip(kept, beta[: len(kept)], strict=True)},
        pooled_intercept=pooled, b1=float(beta[-2]), b2=float(beta[-1]), sigma_rad=float(sigma),
        floor=float(floor), range_min_m=float(r.min()), range_max_m=float(r.max()),
        mae_log=float(loss), points=len(y),
        counts={int(k): int(n) for k, n in zip(keys, counts, strict=True)},
    )  # fmt: skip


def _lad(design: npt.NDArray[np.float64], y: npt.NDArray[np.float64]):  # type: ignore[no-untyped-def]
    """Least-absolute-deviation fit by IRLS: (coefficients, mean |residual|)."""
    weight = np.ones(len(y))
    beta = np.zeros(design.shape[1])
    for _ in range(IRLS_STEPS):
        root = np.sqrt(weight)
        beta, *_ = np.linalg.lstsq(design * root[:, None], y * root, rcond=None)
        weight = 1.0 / np.maximum(np.abs(y - design @ beta), IRLS_FLOOR)
    return beta, float(np.mean(np.abs(y - design @ beta)))
