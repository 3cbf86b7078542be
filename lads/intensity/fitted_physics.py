"""A parametric physics model of a sensor's intensity, fitted from its own real frames.

    ln(I + f) = a_g + b1 ln(R / 1 m) + b2 R / 10 m + s_l(ln R) + ln g(theta; sigma) - 2 alpha R

with I the reflectivity (encoded / full scale), f the encoding's detection floor, a_g the
log reflectance (times the sensor's gain) of group g (a semantic class, or a material),
b1 and b2 a range law (b1 = -2 is the bare radar equation; real sensors compensate range,
`lads diagnose` finds the remission of KITTI rising with range), and g the Oren-Nayar
diffuse law in the backscatter geometry (docs/physics.md §10.1): viewing and lighting
directions coincide, so with A = 1 - 0.5 s/(s + 0.33), B = 0.45 s/(s + 0.09), s = sigma^2,

    g(theta) = A cos(theta) + B sin^2(theta)

(sigma = 0 is Lambert's cos theta; rough surfaces stay bright towards grazing incidence).
alpha is the frame's known extinction (weather), not fitted.

s_l is the range response of laser l, the beam that measured the point: a multi-beam
spinning LiDAR calibrates the intensity of each of its lasers on its own (the HDL-64E's per-
laser calibration carries a gain and a range-dependent focal compensation per laser,
`focal_distance` / `focal_slope`; docs/physics.md §11, effects E2 and E4), so one laser
reads a surface brighter than its neighbour, and differently near than far. s_l is piecewise
linear in ln R with knots at LASER_KNOTS_M (clamped to the fitted support), one curve per
laser, a deviation from the shared range law that a ridge penalty pulls towards zero: a
laser with few points keeps the shared law. A laser is keyed by its elevation in degrees
(the channel's table elevation of the fitting sensor), so the law applies to any frame whose
beam elevations are known, the nearest laser answering; without elevations s_l is 0.

Fitted on training frames only: for each sigma of a grid, the shared parameters by
iteratively reweighted least squares on |residual| (a least-absolute-deviation fit, whose
prediction is the conditional median: the MAE-optimal point value); the sigma with the
smallest mean absolute residual wins, and at that sigma the per-laser curves are fitted with
the shared parameters in one sparse least-absolute-deviation fit. Groups seen fewer than
MIN_GROUP_POINTS times take the pooled intercept. Only returns beyond the near field
(`NEAR_FIELD_M`, where ego-body and mounting-offset returns sit) are fitted, and the law is
evaluated with the range clamped to the fitted support [range_min_m, range_max_m]: a power
law in R extrapolated to a 0.1 m ego return would be several e-folds off. Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from scipy import sparse

from lads.intensity.law_kernel import law_with_lasers, oren_nayar_factor
from lads.sensors.conformity import NEAR_FIELD_M
from lads.sensors.lookup import nearest_entry

SIGMA_GRID_RAD: tuple[float, ...] = tuple(np.round(np.linspace(0.0, 1.2, 13), 3))
MIN_GROUP_POINTS = 50
IRLS_STEPS = 12
IRLS_FLOOR = 1e-3  # |residual| below which a point's weight stops growing
COS_FLOOR = 1e-3
MAX_FIT_POINTS = 400_000  # an even subsample beyond this: the fit has ~40 parameters
# Knots of the per-laser range curves: denser near, where the focal compensation bends.
LASER_KNOTS_M: tuple[float, ...] = (3.0, 5.0, 8.0, 12.0, 20.0, 35.0, 60.0, 120.0)
# Ridge strength of the per-laser curves, in points: a knot of a laser seen by about this
# many (IRLS-weighted) points is pulled halfway to the shared law. Chosen on the validation
# frames of the KITTI, nuScenes and WADS training configs: weaker shrinkage scored the same
# there, stronger worse (a laser's own calibration is real, not noise).
LASER_PRIOR_POINTS = 3.0
MIN_LASER_POINTS = 50  # a laser with fewer fitting points gets no curve of its own


def oren_nayar(cos_theta: npt.ArrayLike, sigma_rad: float) -> npt.NDArray[np.float64]:
    """Backscatter Oren-Nayar factor g(theta) = A cos + B sin^2, (N,) float64 in [0, 1]."""
    a, b = oren_nayar_coefficients(sigma_rad)
    c = np.asarray(cos_theta)
    if c.dtype not in (np.float32, np.float64):
        c = c.astype(np.float64)
    return oren_nayar_factor(c.reshape(-1), a, b, COS_FLOOR).reshape(c.shape)


def oren_nayar_coefficients(sigma_rad: float) -> tuple[float, float]:
    """(A, B) of g(theta) = A cos + B sin^2 for roughness sigma (rad)."""
    s = sigma_rad**2
    return 1.0 - 0.5 * s / (s + 0.33), 0.45 * s / (s + 0.09)


@dataclass(frozen=True)
class FittedPhysics:
    """The fitted law. Attributes as in the module doc; `intercepts` maps group -> a_g;
    `laser_elevation_deg` (L,) the elevation of each laser with a curve of its own and
    `laser_curves` (L, K) its values s_l at the knots `laser_knots_ln` (ln of m)."""

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
    laser_elevation_deg: tuple[float, ...] = ()
    laser_knots_ln: tuple[float, ...] = ()
    laser_curves: tuple[tuple[float, ...], ...] = ()

    def ln_predict(
        self,
        group: npt.ArrayLike,
        range_m: npt.ArrayLike,
        cos_theta: npt.ArrayLike,
        extinction_per_m: float = 0.0,
        elevation_deg: npt.ArrayLike | None = None,
    ) -> npt.NDArray[np.float64]:
        """(N,) predicted ln(I + floor) of points of the given groups, ranges, cosines and
        (optional) beam elevations in degrees."""
        r = np.clip(np.asarray(range_m, dtype=np.float64), self.range_min_m, self.range_max_m)
        g = np.asarray(group, dtype=np.int64)
        a = self.intercept_of(g)
        incidence = np.log(oren_nayar(cos_theta, self.sigma_rad))
        ln_r = np.log(r)
        compiled = np.ndim(extinction_per_m) == 0 and self._compiled_sums(
            elevation_deg, a, incidence, r
        )
        if compiled and elevation_deg is not None:
            # The same sums as below in one compiled pass (`law_kernel`), the same bits.
            return law_with_lasers(
                np.ravel(a),
                np.ravel(ln_r),
                np.ravel(r),
                np.ravel(incidence),
                self.b1,
                self.b2,
                np.ravel(nearest_laser(self.laser_elevation_deg, elevation_deg)),
                np.asarray(self.laser_knots_ln, dtype=np.float64),
                np.asarray(self.laser_curves, dtype=np.float64).ravel(),
                2.0 * float(extinction_per_m),
            ).reshape(r.shape)
        shared = a + self.b1 * ln_r + self.b2 * r / 10.0 + incidence
        return shared + self.laser_term(r, elevation_deg, ln_r) - 2.0 * extinction_per_m * r

    def _compiled_sums(self, elevation_deg: npt.ArrayLike | None, *parts: np.ndarray) -> bool:
        """Whether `law_kernel` can evaluate the sums: per-laser curves of two or more knots,
        elevations given, and every part of the shape of the ranges (no broadcasting)."""
        if elevation_deg is None or len(self.laser_knots_ln) < 2 or not self.laser_curves:
            return False
        shape = parts[-1].shape
        return np.shape(elevation_deg) == shape and all(p.shape == shape for p in parts)

    def laser_term(
        self,
        range_m: npt.NDArray[np.float64],
        elevation_deg: npt.ArrayLike | None,
        ln_range: npt.NDArray[np.float64] | None = None,
    ) -> npt.NDArray[np.float64]:
        """(N,) s_l(ln R) of each point's nearest laser by elevation; 0 without elevations
        or per-laser curves. range_m must already be clamped to the fitted support;
        ln_range, when given, is its log (computed once by `ln_predict`)."""
        if elevation_deg is None or not self.laser_curves:
            return np.zeros(np.shape(range_m))
        laser = nearest_laser(self.laser_elevation_deg, elevation_deg)
        knots = np.asarray(self.laser_knots_ln, dtype=np.float64)
        flat = np.asarray(self.laser_curves, dtype=np.float64).ravel()
        if len(knots) == 1:
            return flat[laser]
        # The hat basis evaluated in place: the curve's two knots around each ln R, blended.
        ln_r = np.log(range_m) if ln_range is None else ln_range
        x = np.clip(ln_r, knots[0], knots[-1])
        j = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(knots) - 2)
        t = (x - knots[j]) / np.diff(knots)[j]
        at = laser * len(knots) + j
        return (1.0 - t) * flat[at] + t * flat[at + 1]

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
        self,
        group: Any,
        range_m: Any,
        cos_theta: Any,
        extinction_per_m: float = 0.0,
        elevation_deg: Any = None,
    ) -> npt.NDArray[np.float64]:
        """(N,) predicted reflectivity (>= 0)."""
        ln = self.ln_predict(group, range_m, cos_theta, extinction_per_m, elevation_deg)
        return np.maximum(np.exp(ln) - self.floor, 0.0)

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> FittedPhysics:
        """Read back `to_json` (the fitted law, without its training tallies)."""
        lasers = raw.get("lasers") or {}
        return cls(
            intercepts={int(k): float(v) for k, v in raw["intercepts"].items()},
            pooled_intercept=float(raw["pooled_intercept"]),
            b1=float(raw["b1_ln_range"]),
            b2=float(raw["b2_per_10m"]),
            sigma_rad=float(raw["sigma_rad"]),
            floor=float(raw["floor"]),
            range_min_m=float(raw["range_min_m"]),
            range_max_m=float(raw["range_max_m"]),
            laser_elevation_deg=tuple(float(v) for v in lasers.get("elevation_deg", ())),
            laser_knots_ln=tuple(float(v) for v in lasers.get("knots_ln_m", ())),
            laser_curves=tuple(tuple(float(v) for v in row) for row in lasers.get("curves", ())),
        )

    def to_json(self) -> dict[str, Any]:
        out = {
            "b1_ln_range": self.b1,
            "b2_per_10m": self.b2,
            "sigma_rad": self.sigma_rad,
            "pooled_intercept": self.pooled_intercept,
            "floor": self.floor,
            "range_min_m": self.range_min_m,
            "range_max_m": self.range_max_m,
            "intercepts": {str(k): v for k, v in sorted(self.intercepts.items())},
            "mae_log_train": self.mae_log,
            "points": self.points,
        }
        if self.laser_curves:
            out["lasers"] = {
                "elevation_deg": list(self.laser_elevation_deg),
                "knots_ln_m": list(self.laser_knots_ln),
                "curves": [list(row) for row in self.laser_curves],
            }
        return out


def nearest_laser(
    table_deg: tuple[float, ...] | npt.ArrayLike, elevation_deg: npt.ArrayLike
) -> npt.NDArray[np.int64]:
    """(N,) index into the increasing elevation table of each elevation's nearest entry."""
    table = np.asarray(table_deg, dtype=np.float64)
    e = np.asarray(elevation_deg)
    if len(table) == 1:
        return np.zeros(e.shape, dtype=np.int64)
    # float32 elevations (a frame's table entries) are widened inside the compiled pass.
    kind = np.float32 if e.dtype == np.float32 else np.float64
    flat: npt.NDArray[Any] = np.ascontiguousarray(e.reshape(-1), dtype=kind)
    return _nearest_entries(table, flat).reshape(e.shape)


@numba.njit(cache=True, nogil=True)
def _nearest_entries(table: npt.NDArray[np.float64], e: npt.NDArray[Any]) -> npt.NDArray[np.int64]:
    """`nearest_laser` for a table of two or more entries, one compiled pass (the same
    comparisons in float64 as its numpy form: ties go to the lower entry)."""
    out = np.empty(e.shape[0], dtype=np.int64)
    previous, answer = math.nan, 0  # a frame's points come ring by ring: reuse the last answer
    for i in range(e.shape[0]):
        v = float(e[i])
        if v != previous:
            answer = nearest_entry(table, v)
            previous = v
        out[i] = answer
    return out


def hat_basis(
    x: npt.NDArray[np.float64], knots: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Piecewise-linear (hat) basis at increasing knots, x clamped to [knots[0], knots[-1]]:
    (N, 2) weights and (N, 2) knot indices, the two neighbouring knots of each x."""
    if len(knots) == 1:
        return np.ones((len(x), 2)) * [1.0, 0.0], np.zeros((len(x), 2), dtype=np.int64)
    xc = np.clip(x, knots[0], knots[-1])
    j = np.clip(np.searchsorted(knots, xc, side="right") - 1, 0, len(knots) - 2)
    t = (xc - knots[j]) / (knots[j + 1] - knots[j])
    return np.stack([1.0 - t, t], axis=1), np.stack([j, j + 1], axis=1)


def fit(
    group: npt.ArrayLike,
    range_m: npt.ArrayLike,
    cos_theta: npt.ArrayLike,
    reflectivity: npt.ArrayLike,
    *,
    floor: float,
    extinction_per_m: npt.ArrayLike | float = 0.0,
    elevation_deg: npt.ArrayLike | None = None,
) -> FittedPhysics:
    """Fit the law to (N,) training points: group ids, ranges (m), cosines, reflectivity,
    and optionally each point's beam elevation in degrees (then per-laser curves are fitted;
    one laser per distinct elevation).

    Raises:
        ValueError: fewer than MIN_GROUP_POINTS points.
    """
    g = np.asarray(group, dtype=np.int64)
    r = np.maximum(np.asarray(range_m, dtype=np.float64), 1e-3)
    c = np.asarray(cos_theta, dtype=np.float64)
    e = None if elevation_deg is None else np.asarray(elevation_deg, dtype=np.float64)
    alpha = np.broadcast_to(np.asarray(extinction_per_m, dtype=np.float64), r.shape)
    y = np.log(np.asarray(reflectivity, dtype=np.float64) + floor) + 2.0 * alpha * r
    idx = _fit_rows(r)
    g, r, c, y = g[idx], r[idx], c[idx], y[idx]
    e = None if e is None else e[idx]
    keys, counts = np.unique(g, return_counts=True)
    kept = keys[counts >= MIN_GROUP_POINTS]
    design, member = _design_matrix(g, r, kept)
    sigma, beta, loss = _best_roughness(design, y, c)
    lasers = _fit_lasers(design, y - np.log(oren_nayar(c, sigma)), r, e, beta)
    if lasers is not None:
        beta, loss = lasers["beta"], lasers["loss"]
    pooled = float(beta[len(kept)]) if (~member).any() else float(np.median(beta[: len(kept)]))
    return FittedPhysics(
        intercepts={int(k): float(v) for k, v in zip(kept, beta[: len(kept)], strict=True)},
        pooled_intercept=pooled,
        b1=float(beta[len(kept) + 1]),
        b2=float(beta[len(kept) + 2]),
        sigma_rad=float(sigma),
        floor=float(floor),
        range_min_m=float(r.min()),
        range_max_m=float(r.max()),
        mae_log=float(loss),
        points=len(y),
        counts={int(k): int(n) for k, n in zip(keys, counts, strict=True)},
        **({} if lasers is None else lasers["law"]),
    )


def _fit_rows(r: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """Indices of the points the law is fitted to: those beyond the near field (every point
    of toy data), thinned evenly to at most MAX_FIT_POINTS.

    Raises:
        ValueError: fewer than MIN_GROUP_POINTS points.
    """
    keep = r >= NEAR_FIELD_M
    if np.count_nonzero(keep) < MIN_GROUP_POINTS:  # toy data: every point is fitted
        keep = np.ones(len(r), dtype=bool)
    idx = np.flatnonzero(keep)
    if len(idx) < MIN_GROUP_POINTS:
        raise ValueError(f"{len(idx)} training points; the law needs at least {MIN_GROUP_POINTS}.")
    if len(idx) > MAX_FIT_POINTS:
        idx = idx[np.linspace(0, len(idx) - 1, MAX_FIT_POINTS).round().astype(np.int64)]
    return idx


def _design_matrix(
    g: npt.NDArray[np.int64], r: npt.NDArray[np.float64], kept: npt.NDArray[np.int64]
) -> tuple[sparse.csr_matrix, npt.NDArray[np.bool_]]:
    """The (N, len(kept) + 3) sparse design of the law and whether each point's group is
    one of `kept` (the others share the pooled intercept)."""
    column = np.searchsorted(kept, g)
    member = (column < len(kept)) & (kept[np.minimum(column, len(kept) - 1)] == g)
    # Columns: one intercept per kept group, the pooled intercept of rare groups, ln R, R/10.
    n, p = len(g), len(kept) + 3
    cols = np.concatenate(
        [np.where(member, column, len(kept)), np.full(n, p - 2), np.full(n, p - 1)]
    )
    values = np.concatenate([np.ones(n), np.log(r), r / 10.0])
    design = sparse.csr_matrix((values, (np.tile(np.arange(n), 3), cols)), shape=(n, p))
    return design, member


def _best_roughness(
    design: sparse.csr_matrix, y: npt.NDArray[np.float64], c: npt.NDArray[np.float64]
) -> tuple[float, npt.NDArray[np.float64], float]:
    """(sigma in rad, coefficients, mean absolute log error) of the least-absolute fit at
    the Oren-Nayar roughness of SIGMA_GRID_RAD that fits best."""
    best = None
    for sigma in SIGMA_GRID_RAD:
        target = y - np.log(oren_nayar(c, sigma))
        beta, loss = _lad(design, target)
        if best is None or loss < best[2]:
            best = (sigma, beta, loss)
    return best  # type: ignore[return-value]


def _fit_lasers(
    design: sparse.csr_matrix,
    y: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
    elevation: npt.NDArray[np.float64] | None,
    start: npt.NDArray[np.float64],
) -> dict[str, Any] | None:
    """The shared parameters and the per-laser curves in one sparse LAD fit (None without
    elevations or without a laser of MIN_LASER_POINTS points)."""
    if elevation is None:
        return None
    table, laser, counts = np.unique(elevation, return_inverse=True, return_counts=True)
    if not (counts >= MIN_LASER_POINTS).any():
        return None
    knots = np.log(np.clip(LASER_KNOTS_M, r.min(), r.max()))
    knots = np.unique(knots)
    basis, cols = hat_basis(np.log(r), knots)
    k = len(knots)
    n, p = design.shape
    rows = np.repeat(np.arange(n), 2)
    laser_x = sparse.csr_matrix(
        (basis.ravel(), (rows, (laser[:, None] * k + cols).ravel())), shape=(n, len(table) * k)
    )
    x = sparse.hstack([design, laser_x], format="csr")
    # A laser with too few points is held at the shared law by an overwhelming ridge.
    strength = np.where(np.repeat(counts, k) >= MIN_LASER_POINTS, 1.0, 1e6) * LASER_PRIOR_POINTS
    beta, loss = _lad(
        x,
        y,
        start=np.r_[start, np.zeros(len(table) * k)],
        ridge_points=np.r_[np.zeros(p), strength],
    )
    curves = beta[p:].reshape(len(table), k)
    law = {
        "laser_elevation_deg": tuple(float(v) for v in table),
        "laser_knots_ln": tuple(float(v) for v in knots),
        "laser_curves": tuple(tuple(float(v) for v in row) for row in curves),
    }
    return {"beta": beta[:p], "loss": loss, "law": law}


def _lad(
    x: sparse.csr_matrix,
    y: npt.NDArray[np.float64],
    *,
    start: npt.NDArray[np.float64] | None = None,
    ridge_points: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], float]:
    """Least-absolute-deviation fit by IRLS on a sparse design: (coefficients, mean
    |residual|). Each step solves the weighted normal equations, plus a ridge of
    `ridge_points` x the mean weight on each coefficient (0: none), from `start` if given."""
    ridge = np.zeros(x.shape[1]) if ridge_points is None else ridge_points
    beta = np.zeros(x.shape[1]) if start is None else start
    weight = np.ones(len(y)) if start is None else _irls_weight(y - x @ beta)
    for _ in range(IRLS_STEPS):
        xtw = x.T.multiply(weight).tocsr()
        gram = (xtw @ x).toarray() + np.diag(ridge * float(weight.mean()) + 1e-9)
        beta = np.linalg.solve(gram, xtw @ y)
        weight = _irls_weight(y - x @ beta)
    return beta, float(np.mean(np.abs(y - x @ beta)))


def _irls_weight(residual: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return 1.0 / np.maximum(np.abs(residual), IRLS_FLOOR)
