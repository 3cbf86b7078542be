"""The baselines a generator must beat, fitted on a target domain's *training* frames only.

A baseline maps an `EvalFrame` to (N,) predicted intensity in the frame's encoding:

    unchanged            what a physics simulator stores: rho cos(theta) exp(-2 alpha R),
                         encoded; no fitting
    physics_rescaled     k I_P, I_P = rho cos(theta) / R^n exp(-2 alpha R), with
                         ln k = median(ln(refl_real + floor) - ln(I_P + 1e-6))
    histogram_global     the frame's points ranked by I_P, ranks mapped to the quantiles of
                         the pooled reference reflectivity
    histogram_per_class  the same within each semantic class against that class's
                         reference quantiles; classes with < 20 reference points (and
                         unlabelled frames) keep the global value
    per_class_median     the median reference reflectivity of the point's class (the
                         MAE-optimal constant per class; unseen classes and unlabelled
                         frames take the pooled median)
    fitted_physics       per-class reflectance x a fitted range law (shared, and per laser)
                         x Oren-Nayar incidence (`lads.intensity.fitted_physics`), the
                         physics `lads diagnose` finds on real scans plus each laser's own
                         calibration, fitted to the reference frames

Pure computation, no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import InputDataError
from lads.intensity import fitted_physics
from lads.intensity.evaluate import (
    EvalFrame,
    FloatArray,
    Method,
    class_ids,
    physics_image,
    unchanged_intensity,
)
from lads.intensity.features import PHYSICS_FLOOR, FrameImage

BASELINES: tuple[str, ...] = (
    "unchanged", "physics_rescaled", "histogram_global", "histogram_per_class",
    "per_class_median", "fitted_physics",
)  # fmt: skip
MIN_CLASS_REFERENCE_POINTS = 20
# Above this many pooled reference values the quantile function is kept as this many exact
# order statistics: the probability error is < 1e-5, the memory bounded.
MAX_QUANTILES = 100_001
UNLABELLED = -1  # the class id of every point of an unlabelled frame


def point_classes(frame: EvalFrame) -> npt.NDArray[np.int64]:
    """(N,) class id of every point, UNLABELLED for unlabelled frames."""
    if frame.labels is None or frame.label_set is None:
        return np.full(frame.n_points, UNLABELLED, dtype=np.int64)
    return class_ids(frame.labels, frame.label_set)


class _LastImage:
    """frame_image of the frame seen last. `evaluate` runs every method on one frame before
    the next, so the baselines share one projection per frame instead of one each."""

    def __init__(self, range_exponent: float) -> None:
        self.range_exponent = range_exponent
        self._frame: EvalFrame | None = None
        self._image: FrameImage | None = None

    def __call__(self, frame: EvalFrame) -> FrameImage:
        if self._frame is not frame or self._image is None:
            self._image = physics_image(frame, self.range_exponent)
            self._frame = frame
        return self._image


@dataclass(frozen=True)
class Quantiles:
    """An empirical quantile function: `value[j]` is the quantile at `probability[j]`.

    Attributes:
        probability: (M,) float64 increasing in (0, 1), (j + 0.5) / count of order stats.
        value: (M,) float64 non-decreasing reflectivity.
        count: number of values it was built from.
    """

    probability: npt.NDArray[np.float64]
    value: npt.NDArray[np.float64]
    count: int

    @classmethod
    def of(cls, values: npt.ArrayLike) -> Quantiles:
        ordered = np.sort(np.asarray(values, dtype=np.float64))
        m = len(ordered)
        j = np.arange(m)
        if m > MAX_QUANTILES:
            j = np.unique(np.linspace(0, m - 1, MAX_QUANTILES).round().astype(np.int64))
        return cls((j + 0.5) / m, ordered[j], m)

    def at(self, q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Values at probabilities q in [0, 1], linear between order statistics."""
        return np.interp(q, self.probability, self.value)


def quantile_match(physics: npt.ArrayLike, table: Quantiles) -> npt.NDArray[np.float64]:
    """Give the i-th smallest of n physics values the reference quantile at (i + 0.5) / n.

    Ties keep input order (stable sort), so equal I_P still spread over the quantiles.
    """
    x = np.asarray(physics)
    order = np.argsort(x, kind="stable")
    q = np.empty(len(x), dtype=np.float64)
    q[order] = (np.arange(len(x)) + 0.5) / max(len(x), 1)
    return table.at(q)


@dataclass(frozen=True)
class Unchanged:
    """Baseline: the simulator's own intensity, rho cos(theta) exp(-2 alpha R), encoded."""

    images: _LastImage = field(repr=False)

    def __call__(self, frame: EvalFrame) -> FloatArray:
        return unchanged_intensity(frame, self.images(frame))


@dataclass(frozen=True)
class PhysicsRescaled:
    """Baseline: k I_P encoded; k (unitless per m^-n) fitted on the reference frames."""

    k: float
    images: _LastImage = field(repr=False)

    def __call__(self, frame: EvalFrame) -> FloatArray:
        refl = self.k * self.images(frame).physics.astype(np.float64)
        return frame.profile.intensity.from_reflectivity(refl)


@dataclass(frozen=True)
class HistogramGlobal:
    """Baseline: I_P ranks mapped onto the pooled reference reflectivity quantiles."""

    table: Quantiles = field(repr=False)
    images: _LastImage = field(repr=False)

    def __call__(self, frame: EvalFrame) -> FloatArray:
        refl = quantile_match(self.images(frame).physics, self.table)
        return frame.profile.intensity.from_reflectivity(refl)


@dataclass(frozen=True)
class HistogramPerClass:
    """Baseline: quantile matching within each class against that class's reference.

    Points of a class without a reference table (fewer than MIN_CLASS_REFERENCE_POINTS
    reference points) keep the global baseline's value, i.e. their rank among all the
    frame's points, which places them where their I_P sits in the scene.

    Attributes:
        table: global reference quantiles.
        class_tables: (label set, class id) -> that class's reference quantiles.
    """

    table: Quantiles = field(repr=False)
    class_tables: dict[tuple[str | None, int], Quantiles] = field(repr=False)
    images: _LastImage = field(repr=False)

    def __call__(self, frame: EvalFrame) -> FloatArray:
        physics = self.images(frame).physics
        refl = quantile_match(physics, self.table)
        if frame.labels is not None and frame.label_set is not None:
            cls = class_ids(frame.labels, frame.label_set)
            for cid in np.unique(cls):
                table = self.class_tables.get((frame.label_set, int(cid)))
                if table is not None:
                    members = np.flatnonzero(cls == cid)
                    refl[members] = quantile_match(physics[members], table)
        return frame.profile.intensity.from_reflectivity(refl)


@dataclass(frozen=True)
class PerClassMedian:
    """Baseline: the class's median reference reflectivity (pooled median for others)."""

    medians: dict[tuple[str | None, int], float] = field(repr=False)
    pooled: float

    def __call__(self, frame: EvalFrame) -> FloatArray:
        cls = point_classes(frame)
        refl = np.full(frame.n_points, self.pooled)
        for cid in np.unique(cls):
            value = self.medians.get((frame.label_set, int(cid)))
            if value is not None:
                refl[cls == cid] = value
        return frame.profile.intensity.from_reflectivity(refl)


@dataclass(frozen=True)
class FittedPhysicsBaseline:
    """Baseline: the fitted law of `lads.intensity.fitted_physics`, per class, encoded."""

    law: fitted_physics.FittedPhysics
    label_set: str | None
    images: _LastImage = field(repr=False)

    def __call__(self, frame: EvalFrame) -> FloatArray:
        image = self.images(frame)
        cls = point_classes(frame) if frame.label_set == self.label_set else None
        if cls is None:
            cls = np.full(frame.n_points, UNLABELLED, dtype=np.int64)
        refl = self.law.predict(
            cls, image.range_m, image.cos_incidence, frame.extinction_per_m, image.elevation_deg
        )
        return frame.profile.intensity.from_reflectivity(refl)


def fit_baselines(
    reference: Iterable[EvalFrame], *, range_exponent: float = 1.0
) -> dict[str, Method]:
    """Fit every baseline on real reference frames of the target domain.

    Args:
        reference: real *training* frames of the target domain (never a validation or test
            frame).
        range_exponent: n of I_P = rho cos(theta) / R^n exp(-2 alpha R).

    Returns:
        {name: method} for the names in BASELINES, in that order.

    Raises:
        InputDataError: no reference frames, or none with points.
    """
    frames = [f for f in reference if f.n_points]
    if not frames:
        raise InputDataError(
            "fit_baselines: no reference frames with points; pass the real training frames of "
            "the target domain (not the validation or test frames) to fit the baselines on."
        )
    images = _LastImage(range_exponent)
    parts = [_reference_points(f, images) for f in frames]
    refl = np.concatenate([p["refl"] for p in parts])
    log_ratio = np.concatenate([p["log_ratio"] for p in parts])
    cls_all = np.concatenate([p["cls"] for p in parts])
    sets = np.concatenate([[f.label_set or ""] * f.n_points for f in frames])
    table = Quantiles.of(refl)
    class_tables: dict[tuple[str | None, int], Quantiles] = {}
    medians: dict[tuple[str | None, int], float] = {}
    for label_set in np.unique(sets):
        for cid in np.unique(cls_all[sets == label_set]):
            values = refl[(sets == label_set) & (cls_all == cid)]
            key = (label_set or None, int(cid))
            medians[key] = float(np.median(values))
            if cid != UNLABELLED and len(values) >= MIN_CLASS_REFERENCE_POINTS:
                class_tables[key] = Quantiles.of(values)
    label_set = frames[0].label_set
    law = fitted_physics.fit(
        cls_all,
        np.concatenate([p["range"] for p in parts]),
        np.concatenate([p["cos"] for p in parts]),
        refl,
        floor=frames[0].profile.intensity.detection_floor,
        extinction_per_m=np.concatenate([[f.extinction_per_m] * f.n_points for f in frames]),
        elevation_deg=np.concatenate([p["elevation"] for p in parts]),
    )
    return {
        "unchanged": Unchanged(images),
        "physics_rescaled": PhysicsRescaled(float(np.exp(np.median(log_ratio))), images),
        "histogram_global": HistogramGlobal(table, images),
        "histogram_per_class": HistogramPerClass(table, class_tables, images),
        "per_class_median": PerClassMedian(medians, float(np.median(refl))),
        "fitted_physics": FittedPhysicsBaseline(law, label_set, images),
    }


def _reference_points(frame: EvalFrame, images: _LastImage) -> dict[str, Any]:
    image = images(frame)
    encoding = frame.profile.intensity
    refl = encoding.to_reflectivity(frame.intensity)
    physics = image.physics.astype(np.float64)
    return {
        "refl": refl,
        "cls": point_classes(frame),
        "range": image.range_m.astype(np.float64),
        "cos": image.cos_incidence.astype(np.float64),
        "elevation": image.elevation_deg,
        "log_ratio": np.log(refl + encoding.detection_floor) - np.log(physics + PHYSICS_FLOOR),
    }


@dataclass(frozen=True)
class InSampleBound:
    """Not a method: the conditional median reflectivity of the *evaluated* frames' own
    points in cells of class x BOUND_BINS log-range bins x BOUND_BINS incidence bins.
    Fitted on the very points it predicts, it bounds from above what any per-point
    function of class, range and incidence can score there (MAE and rank correlation)."""

    medians: dict[int, float] = field(repr=False)
    images: _LastImage = field(repr=False)

    @classmethod
    def of(cls, frames: Iterable[EvalFrame], range_exponent: float = 1.0) -> InSampleBound:
        images = _LastImage(range_exponent)
        codes, values = [], []
        for frame in frames:
            codes.append(_bound_cells(frame, images))
            values.append(frame.profile.intensity.to_reflectivity(frame.intensity))
        code, refl = np.concatenate(codes), np.concatenate(values)
        order = np.argsort(code, kind="stable")
        keys, starts = np.unique(code[order], return_index=True)
        groups = np.split(refl[order], starts[1:])
        return cls({int(k): float(np.median(g)) for k, g in zip(keys, groups, strict=True)}, images)

    def __call__(self, frame: EvalFrame) -> FloatArray:
        code = _bound_cells(frame, self.images)
        refl = np.array([self.medians.get(int(k), 0.0) for k in code])
        return frame.profile.intensity.from_reflectivity(refl)


BOUND_BINS = 20
BOUND_MAX_RANGE_M = 120.0


def _bound_cells(frame: EvalFrame, images: _LastImage) -> npt.NDArray[np.int64]:
    """(N,) int64 cell code of every point: class, log-range bin, incidence bin."""
    image = images(frame)
    r = np.clip(image.range_m.astype(np.float64), 1.0, BOUND_MAX_RANGE_M)
    rb = np.minimum(
        (np.log(r) / np.log(BOUND_MAX_RANGE_M) * BOUND_BINS).astype(np.int64), BOUND_BINS - 1
    )
    cb = np.minimum((image.cos_incidence * BOUND_BINS).astype(np.int64), BOUND_BINS - 1)
    cls = point_classes(frame) + 1  # UNLABELLED (-1) becomes 0
    return (cls * BOUND_BINS + rb) * BOUND_BINS + cb
