"""The generalisation targets a learned intensity model is held to on frames it never saw.

Each target compares the generator with a baseline fitted on the target's training frames
(`lads.intensity.baselines`) or with a fixed threshold, on the pooled metrics of
`lads.intensity.evaluate`. They are checked on every evaluation and written into its
report, met or missed; the test split's verdicts are the ones docs/intensity.md reports.

    mae_vs_median        generator MAE <= MAE_FRACTION_OF_MEDIAN x the per-class median's
    mae_vs_fitted_law    generator MAE < the fitted physics law's
    cell_w1              generator cell-conditional W1 < every baseline's
    spearman             Spearman rho >= MIN_SPEARMAN[encoding] (encodings listed there)
    class_ratio:<class>  mean predicted / mean real within CLASS_RATIO_BOUNDS, for every
                         class with >= MIN_CLASS_POINTS points
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

MEDIAN_BASELINE = "per_class_median"
LAW_BASELINE = "fitted_physics"
MAE_FRACTION_OF_MEDIAN = 0.85
# A rank target is set where the remission is a calibrated reflectivity with a fine
# encoding (KITTI's 0.01 steps); other encodings report their rank correlation unjudged.
MIN_SPEARMAN: dict[str, float] = {"hdl64e": 0.65}
CLASS_RATIO_BOUNDS: tuple[float, float] = (0.8, 1.25)
MIN_CLASS_POINTS = 1000


def check(
    pooled: Mapping[str, Mapping[str, Any]],
    class_points: Mapping[str, int],
    encoding: str,
    *,
    subject: str,
    bound_prefix: str,
) -> list[dict[str, Any]]:
    """Every target that applies, as rows {"target", "value", "threshold", "met"}.

    Args:
        pooled: method -> pooled metrics (`evaluate.METRIC_KEYS`).
        class_points: class name -> number of evaluated points of that class.
        encoding: the evaluated frames' profile name (selects the rank target).
        subject: the method judged (the generator).
        bound_prefix: methods named so are reference bounds, not baselines.

    Returns:
        Rows in the order of the module docstring; none without the subject. A target
        whose baseline is missing, or whose value is undefined, is reported as not met.
    """
    mine = pooled.get(subject)
    if mine is None:
        return []
    rows = []
    median = pooled.get(MEDIAN_BASELINE, {}).get("mae_reflectivity")
    limit = None if median is None else MAE_FRACTION_OF_MEDIAN * median
    rows.append(_row("mae_vs_median", mine["mae_reflectivity"], limit, "<="))
    law = pooled.get(LAW_BASELINE, {}).get("mae_reflectivity")
    rows.append(_row("mae_vs_fitted_law", mine["mae_reflectivity"], law, "<"))
    others = [
        row["cell_w1_reflectivity"]
        for name, row in pooled.items()
        if name != subject and not name.startswith(bound_prefix)
    ]
    finite = [v for v in others if v is not None and math.isfinite(v)]
    rows.append(_row("cell_w1", mine["cell_w1_reflectivity"], min(finite, default=None), "<"))
    if encoding in MIN_SPEARMAN:
        rows.append(_row("spearman", mine["spearman_rho"], MIN_SPEARMAN[encoding], ">="))
    low, high = CLASS_RATIO_BOUNDS
    for name, count in class_points.items():
        if count >= MIN_CLASS_POINTS:
            ratio = mine["class_ratio"].get(name)
            row = _row(f"class_ratio:{name}", ratio, [low, high], "in")
            rows.append({**row, "points": int(count)})
    return rows


def _row(target: str, value: Any, threshold: Any, relation: str) -> dict[str, Any]:
    return {
        "target": target,
        "value": value,
        "relation": relation,
        "threshold": threshold,
        "met": _met(value, threshold, relation),
    }


def _met(value: Any, threshold: Any, relation: str) -> bool:
    if value is None or threshold is None or not math.isfinite(value):
        return False
    if relation == "in":
        return bool(threshold[0] <= value <= threshold[1])
    if relation == "<=":
        return bool(value <= threshold)
    if relation == "<":
        return bool(value < threshold)
    return bool(value >= threshold)


def lines(rows: list[dict[str, Any]]) -> list[str]:
    """Markdown bullet lines, one per target: met or MISSED, value against threshold."""
    out = []
    for row in rows:
        threshold = row["threshold"]
        shown = (
            f"[{threshold[0]:.4g}, {threshold[1]:.4g}]"
            if isinstance(threshold, list)
            else "–"
            if threshold is None
            else f"{threshold:.4g}"
        )
        value = row["value"]
        text = "–" if value is None or not math.isfinite(value) else f"{value:.4g}"
        verdict = "met" if row["met"] else "MISSED"
        out.append(f"- {row['target']}: {verdict}, {text} (needs {row['relation']} {shown})")
    return out
