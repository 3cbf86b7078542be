"""The metrics of `lads.intensity.evaluate`: one prediction against the real intensity of
the same points (paired, per-class, per-cell and retro-reflective contrast), and which method
scores best (docs/intensity.md §5)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import stats

from lads.jsontypes import json_types

SUBJECT = "generator"
# Methods fitted on the evaluated frames themselves (an in-sample upper bound of what some
# inputs allow); reported beside the methods, never compared as one.
BOUND_PREFIX = "bound_"
MIN_CELL_POINTS = 30
MIN_RATIO_POINTS = 50
# A handful of sign-edge points would make the contrast mostly noise.
MIN_RETRO_POINTS = 10
# The pooled metrics the subject is compared on in `summary["beats"]`.
SUMMARY_METRICS: tuple[str, ...] = ("mae_reflectivity", "cell_w1_reflectivity")
SIGNIFICANT_DIGITS = 6


@dataclass(frozen=True)
class PointContext:
    """Per-point context of the metrics for one frame or the pooled frames."""

    real: npt.NDArray[np.float64]  # encoded
    full_scale: float
    cls: npt.NDArray[np.int64]  # code into the class vocabulary
    cell: npt.NDArray[np.int64]  # (class, range bin, cos bin) cell id
    retro: npt.NDArray[np.bool_] | None  # None: no retro-reflective class is known

    @property
    def real_refl(self) -> npt.NDArray[np.float64]:
        return self.real / self.full_scale


def pooled_retro(contexts: list[PointContext]) -> npt.NDArray[np.bool_] | None:
    """The retro-reflective mask of pooled frames (None when no frame knows its retros)."""
    if all(c.retro is None for c in contexts):
        return None
    return np.concatenate(
        [np.zeros(len(c.real), bool) if c.retro is None else c.retro for c in contexts]
    )


def pooled_context(contexts: list[PointContext]) -> PointContext:
    """The points of all `contexts` (frames sharing one encoding) as one context."""
    return PointContext(
        real=np.concatenate([c.real for c in contexts]),
        full_scale=contexts[0].full_scale,
        cls=np.concatenate([c.cls for c in contexts]),
        cell=np.concatenate([c.cell for c in contexts]),
        retro=pooled_retro(contexts),
    )


def metrics(
    ctx: PointContext, prediction: npt.ArrayLike, class_names: tuple[str, ...]
) -> dict[str, Any]:
    """METRIC_KEYS (lads.intensity.evaluate) of one prediction against the real intensity
    of the same points."""
    pred = np.asarray(prediction, dtype=np.float64)
    pred_refl = pred / ctx.full_scale
    real_refl = ctx.real_refl
    ratios = _class_ratios(ctx, pred, class_names)
    finite = [v for v in ratios.values() if math.isfinite(v) and v > 0]
    cell_w1, cell_ks, cells, coverage = _cell_distances(ctx.cell, pred_refl, real_refl)
    retro_pred = _contrast(pred, ctx.retro)
    retro_real = _contrast(ctx.real, ctx.retro)
    return {
        "points": len(pred),
        "mae_encoded": float(np.mean(np.abs(pred - ctx.real))),
        "mae_reflectivity": float(np.mean(np.abs(pred_refl - real_refl))),
        "pearson_r": _correlation(stats.pearsonr, pred, ctx.real),
        "spearman_rho": _correlation(stats.spearmanr, pred, ctx.real),
        "class_ratio": ratios,
        "class_ratio_count": len(ratios),
        "class_ratio_mean_abs_log": (
            float(np.mean(np.abs(np.log(finite)))) if finite else math.nan
        ),
        "class_zero_share_pred": _class_zero_shares(ctx.cls, pred, class_names),
        "class_zero_share_real": _class_zero_shares(ctx.cls, ctx.real, class_names),
        "cell_w1_reflectivity": cell_w1,
        "cell_ks": cell_ks,
        "cells": cells,
        "cell_coverage": coverage,
        "global_w1_reflectivity": float(stats.wasserstein_distance(pred_refl, real_refl)),
        "global_ks": float(stats.ks_2samp(pred_refl, real_refl, method="asymp").statistic),
        "retro_contrast_pred": retro_pred,
        "retro_contrast_real": retro_real,
        "retro_contrast_ratio": _ratio(retro_pred, retro_real),
    }


def _correlation(fn: Callable[..., Any], a: npt.NDArray[Any], b: npt.NDArray[Any]) -> float:
    # A constant input has no correlation; scipy would warn and return NaN.
    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return math.nan
    return float(fn(a, b).statistic)


def _class_ratios(
    ctx: PointContext, pred: npt.NDArray[np.float64], class_names: tuple[str, ...]
) -> dict[str, float]:
    size = len(class_names)
    counts = np.bincount(ctx.cls, minlength=size)
    pred_sum = np.bincount(ctx.cls, weights=pred, minlength=size)
    real_sum = np.bincount(ctx.cls, weights=ctx.real, minlength=size)
    return {
        class_names[c]: _ratio(float(pred_sum[c]), float(real_sum[c]))
        for c in np.flatnonzero(counts >= MIN_RATIO_POINTS)
    }


def _class_zero_shares(
    cls: npt.NDArray[np.int64], values: npt.NDArray[np.float64], class_names: tuple[str, ...]
) -> dict[str, float]:
    """{class: share of its points whose value is exactly 0} for the classes of
    `_class_ratios`. A real sensor may report exact zeros for a large share of a class (KITTI
    remission does); a median-seeking point prediction then sits far below the class mean."""
    size = len(class_names)
    counts = np.bincount(cls, minlength=size)
    zeros = np.bincount(cls, weights=(values == 0).astype(np.float64), minlength=size)
    return {
        class_names[c]: float(zeros[c] / counts[c])
        for c in np.flatnonzero(counts >= MIN_RATIO_POINTS)
    }


def _cell_distances(
    cell: npt.NDArray[np.int64],
    pred: npt.NDArray[np.float64],
    real: npt.NDArray[np.float64],
) -> tuple[float, float, int, float]:
    order = np.argsort(cell, kind="stable")
    _, starts, counts = np.unique(cell[order], return_index=True, return_counts=True)
    w1_sum = ks_sum = 0.0
    used = covered = 0
    for start, count in zip(starts, counts, strict=True):
        if count < MIN_CELL_POINTS:
            continue
        members = order[start : start + count]
        w1_sum += count * stats.wasserstein_distance(pred[members], real[members])
        ks_sum += count * stats.ks_2samp(pred[members], real[members], method="asymp").statistic
        used += 1
        covered += int(count)
    if not covered:
        return math.nan, math.nan, 0, 0.0
    return w1_sum / covered, ks_sum / covered, used, covered / len(cell)


def _contrast(values: npt.NDArray[np.float64], retro: npt.NDArray[np.bool_] | None) -> float:
    if retro is None:
        return math.nan
    n_retro = int(np.count_nonzero(retro))
    if n_retro < MIN_RETRO_POINTS or n_retro == len(values):
        return math.nan
    return _ratio(float(values[retro].mean()), float(values[~retro].mean()))


def _ratio(a: float, b: float) -> float:
    if not (math.isfinite(a) and math.isfinite(b)) or b == 0:
        return math.nan
    return a / b


# How each headline metric is judged: lower is better, higher is better, or closest to 1.
DIRECTIONS: dict[str, str] = {
    "mae_encoded": "min",
    "mae_reflectivity": "min",
    "pearson_r": "max",
    "spearman_rho": "max",
    "class_ratio_mean_abs_log": "min",
    "cell_w1_reflectivity": "min",
    "cell_ks": "min",
    "global_w1_reflectivity": "min",
    "global_ks": "min",
    "retro_contrast_ratio": "one",
}


def _score(metric: str, value: Any) -> float:
    """A number where smaller is better, NaN when the value is missing."""
    if value is None or not math.isfinite(value):
        return math.nan
    direction = DIRECTIONS[metric]
    if direction == "max":
        return -value
    if direction == "one":
        return abs(math.log(value)) if value > 0 else math.inf
    return float(value)


def best_methods(table: Mapping[str, Mapping[str, Any]], metric: str) -> list[str]:
    """Methods with the best value of `metric` (ties all listed; none if all missing)."""
    scores = {m: _score(metric, row.get(metric)) for m, row in table.items()}
    finite = [s for s in scores.values() if not math.isnan(s)]
    if not finite:
        return []
    top = min(finite)
    # Equal up to float rounding is a tie, not a win.
    return [m for m, s in scores.items() if not math.isnan(s) and s <= top + 1e-12 * abs(top)]


def summarise(pooled: Mapping[str, Mapping[str, Any]], subject: str = SUBJECT) -> dict[str, Any]:
    """Which other methods `subject` beats on the pooled SUMMARY_METRICS (missing = no).
    Bounds (methods named `BOUND_PREFIX...`, fitted on the evaluated frames themselves) are
    reference points, not competitors: they are neither beaten nor best."""
    pooled = {m: row for m, row in pooled.items() if not m.startswith(BOUND_PREFIX)}
    best = {metric: best_methods(pooled, metric) for metric in DIRECTIONS}
    if subject not in pooled:
        return {"subject": None, "metrics": list(SUMMARY_METRICS), "beats": {}, "best": best}
    beats = {
        metric: {
            other: bool(_score(metric, pooled[subject][metric]) < _score(metric, row[metric]))
            for other, row in pooled.items()
            if other != subject
        }
        for metric in SUMMARY_METRICS
    }
    return {"subject": subject, "metrics": list(SUMMARY_METRICS), "beats": beats, "best": best}


def jsonable(value: Any) -> Any:
    """Plain JSON types with floats rounded to SIGNIFICANT_DIGITS (`lads.jsontypes`)."""
    return json_types(value, significant=SIGNIFICANT_DIGITS)
