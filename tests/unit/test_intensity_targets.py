"""The generalisation targets: each one can be met and missed."""

from __future__ import annotations

import math

from lads.intensity import targets


def _row(mae, w1, rho=0.7, ratios=None):
    return {
        "mae_reflectivity": mae,
        "cell_w1_reflectivity": w1,
        "spearman_rho": rho,
        "class_ratio": ratios or {},
    }


def _pooled(generator):
    return {
        "generator": generator,
        "per_class_median": _row(0.10, 0.08),
        "fitted_physics": _row(0.09, 0.07),
        "bound_in_sample": _row(0.01, 0.001),  # a bound is never a baseline to beat
    }


def _by_name(rows):
    return {r["target"]: r for r in rows}


def test_every_target_met():
    gen = _row(0.08, 0.05, 0.7, {"car": 1.1, "road": 0.9, "pole": 3.0})
    points = {"car": 5000, "road": 9000, "pole": 999}
    rows = _by_name(
        targets.check(_pooled(gen), points, "hdl64e", subject="generator", bound_prefix="bound_")
    )
    assert set(rows) == {
        "mae_vs_median",
        "mae_vs_fitted_law",
        "cell_w1",
        "spearman",
        "class_ratio:car",
        "class_ratio:road",
    }
    assert all(r["met"] for r in rows.values())
    assert math.isclose(rows["mae_vs_median"]["threshold"], 0.085)
    assert rows["cell_w1"]["threshold"] == 0.07  # the best baseline, not the bound


def test_each_target_can_be_missed():
    gen = _row(0.095, 0.07, 0.64, {"car": 0.79})
    rows = _by_name(
        targets.check(
            _pooled(gen), {"car": 1000}, "hdl64e", subject="generator", bound_prefix="bound_"
        )
    )
    assert not any(r["met"] for r in rows.values())
    text = "\n".join(targets.lines(list(rows.values())))
    assert text.count("MISSED") == 5


def test_missing_baseline_or_value_is_not_met_and_rank_target_only_where_set():
    gen = _row(0.05, float("nan"), 0.9, {})
    rows = _by_name(
        targets.check({"generator": gen}, {}, "hdl32e", subject="generator", bound_prefix="bound_")
    )
    assert "spearman" not in rows
    assert not rows["mae_vs_median"]["met"] and not rows["cell_w1"]["met"]
    assert targets.check({}, {}, "hdl64e", subject="generator", bound_prefix="bound_") == []
