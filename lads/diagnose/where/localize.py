"""Where do simulated and real intensities and returns differ? (docs/diagnose.md §5.2)

Residuals r = ln(I_real + h) - ln(I_sim + h) (h = half a quantisation step) on beams both
recordings returned, and the dropout indicator d_drop on beams the simulation returned, are
binned by nine features (`lads.diagnose.where.binning`). Per bin: count, mean and median with 95%
CIs, and the drop rate with its CI, all from one cluster bootstrap over `table.group`
(groups, never points, are the independent units: docs/diagnose.md §2 item 4). Every feature and
target is tested (trend and omnibus, cluster-robust; `lads.diagnose.where.binstats` describes the
tests), Benjamini-Hochberg runs over all of them, and the significant ones become ranked
"where" statements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.diagnose.config import CONFIG
from lads.diagnose.data.table import BeamTable
from lads.diagnose.where.binning import F64, FEATURES, I64, Binning, Feature
from lads.diagnose.where.binstats import (
    MIN_BIN_SHARE,
    MIN_EFFECT_GROUPS,
    Q_THRESHOLD,
    GroupBootstrap,
    bh_q_values,
    target_stats,
)
from lads.errors import InputDataError
from lads.jsontypes import json_types

MIN_HEATMAP_ROWS = CONFIG.localize.min_heatmap_rows
TARGETS = ("intensity", "dropout")
HEATMAPS = (("range_x_cos", "range", "cos_incidence"), ("ring_x_range", "ring", "range"),
            ("class_x_range", "class", "range"))  # fmt: skip


@dataclass(frozen=True, slots=True)
class Residuals:
    """Per-row residuals of a beam table.

    Attributes:
        r: (N,) float64 ln(I_real + h) - ln(I_sim + h); NaN unless both returned.
        d_drop: (N,) bool the simulation returned the beam, reality did not.
        d_extra: (N,) bool reality returned the beam, the simulation did not.
    """

    r: F64
    d_drop: npt.NDArray[np.bool_]
    d_extra: npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class BinStats:
    """One target (intensity residual or dropout) binned by one feature; arrays are (K,).

    Attributes:
        count: rows per bin (intensity: both returned; dropout: sim returned).
        n_groups: groups with rows in the bin.
        mean, mean_low, mean_high: mean of r (or the drop rate) and its 95% bootstrap CI.
        median, median_low, median_high: median of r and its Woodruff 95% CI (NaN for
            dropout).
        p_value: combined p-value (module docstring); NaN when untestable.
        p_trend, p_omnibus: the two tests behind it (p_trend NaN for categorical features).
        q_value: Benjamini-Hochberg q over all features and targets.
        effect_size: max - min of the eligible bin means (log units or rate).
        extreme_bins: labels of the two extreme eligible bins, in feature order.
        slope, slope_se: cluster-robust trend slope per feature unit and its SE.
        direction: "increases", "decreases" or "varies" along the feature.
        agreement: ground vs non-ground comparison (range and cos_incidence), else None.
    """

    count: I64
    n_groups: I64
    mean: F64
    mean_low: F64
    mean_high: F64
    median: F64
    median_low: F64
    median_high: F64
    p_value: float
    p_trend: float
    p_omnibus: float
    q_value: float
    effect_size: float
    extreme_bins: tuple[str, ...]
    slope: float
    slope_se: float
    direction: str
    agreement: dict[str, Any] | None


@dataclass(frozen=True, slots=True)
class FeatureProfile:
    """Both targets binned by one feature (`intensity`, `dropout`), plus the bins."""

    name: str
    title: str
    unit: str
    ordered: bool
    labels: tuple[str, ...]
    centres: F64
    intensity: BinStats
    dropout: BinStats

    # The intensity target's numbers under the names a reader looks for first.
    @property
    def counts(self) -> I64:
        return self.intensity.count

    @property
    def mean(self) -> F64:
        return self.intensity.mean

    @property
    def drop_rate(self) -> F64:
        return self.dropout.mean


@dataclass(frozen=True, slots=True)
class Heatmap:
    """Mean r over two binned features; NaN in cells with < MIN_HEATMAP_ROWS rows."""

    rows: str
    cols: str
    row_labels: tuple[str, ...]
    col_labels: tuple[str, ...]
    mean: F64  # (K_rows, K_cols)
    count: I64  # (K_rows, K_cols)


@dataclass(frozen=True, slots=True)
class Localization:
    """The output of `localize`.

    Attributes:
        features: feature name -> profile, in FEATURES order (class absent if unlabelled).
        statements: ranked "where" statements, intensity first, then dropout (each ranked
            by effect size): {"feature", "target", "bins", "effect_size", "direction",
            "q_value", "text"}.
        heatmaps: "range_x_cos", "ring_x_range", "class_x_range" (labelled tables only).
        n_rows, n_groups, n_boot: table rows, bootstrap groups and replicates.
        residual_given: True when the caller passed the residual (e.g. after a fit).
    """

    features: dict[str, FeatureProfile]
    statements: list[dict[str, Any]]
    heatmaps: dict[str, Heatmap]
    n_rows: int
    n_groups: int
    n_boot: int
    residual_given: bool


def residuals(table: BeamTable) -> Residuals:
    """r, d_drop and d_extra of every row (docs/diagnose.md §5.2).

    Args:
        table: the beam table; intensities in stored units.

    Returns:
        Residuals with (N,) arrays; r is NaN where either recording has no return.
    """
    h = table.sensor.half_step
    both = table.ret_sim & table.ret_real
    r = np.full(len(table), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        r[both] = np.log(table.i_real[both].astype(np.float64) + h) - np.log(
            table.i_sim[both].astype(np.float64) + h
        )
    return Residuals(r, table.ret_sim & ~table.ret_real, table.ret_real & ~table.ret_sim)


def localize(
    table: BeamTable,
    residual: npt.ArrayLike | None = None,
    *,
    rng: np.random.Generator,
    n_boot: int = 200,
    max_statements: int = 10,
    drop_residual: npt.ArrayLike | None = None,
) -> Localization:
    """Bin the residual and the dropout by every feature, test, and rank statements.

    Args:
        table: the beam table (N rows).
        residual: (N,) intensity residual to localize instead of `residuals(table).r`, e.g.
            the residual after a fit; NaN rows are left out.
        rng: the bootstrap's generator.
        n_boot: cluster bootstrap replicates.
        max_statements: statements kept.
        drop_residual: (N,) dropout residual (e.g. d_drop - fitted drop probability) used
            instead of d_drop on rows the simulation returned; NaN rows are left out.

    Returns:
        The Localization.

    Raises:
        InputDataError: a residual without one value per row, an empty table, n_boot < 2.
    """
    n = len(table)
    if n == 0 or n_boot < 2:
        raise InputDataError(
            f"localize: {n} rows and n_boot = {n_boot}; need a non-empty beam table and at "
            "least 2 bootstrap replicates."
        )
    res = residuals(table)
    r = res.r if residual is None else _per_row(residual, n, "residual")
    d = res.d_drop.astype(np.float64)
    if drop_residual is not None:
        d = _per_row(drop_residual, n, "drop_residual")
    d = np.where(table.ret_sim, d, np.nan)
    boot = _group_bootstrap(table, rng, n_boot)
    binnings: dict[str, tuple[Feature, Binning]] = {}
    for feature in FEATURES:
        binning = feature.bin(table)
        if binning is not None:
            binnings[feature.name] = (feature, binning)
    features = _feature_profiles(table, r, d, binnings, boot)
    heatmaps = {
        key: _heatmap(r, binnings[a][1], binnings[b][1], a, b)
        for key, a, b in HEATMAPS
        if a in binnings and b in binnings
    }
    return Localization(
        features,
        _statements(features, max_statements),
        heatmaps,
        n,
        boot.n_groups,
        n_boot,
        residual is not None,
    )


def _group_bootstrap(table: BeamTable, rng: np.random.Generator, n_boot: int) -> GroupBootstrap:
    """`n_boot` cluster bootstrap replicates: multinomial weights over the table's groups."""
    groups, gid = np.unique(table.group, return_inverse=True)
    n_groups = groups.size
    weights = rng.multinomial(n_groups, np.full(n_groups, 1.0 / n_groups), size=n_boot)
    weights_t = np.ascontiguousarray(weights.T, np.float64)
    return GroupBootstrap(gid.astype(np.int64), n_groups, weights_t)


def _feature_profiles(
    table: BeamTable,
    r: npt.NDArray[np.float64],
    d: npt.NDArray[np.float64],
    binnings: dict[str, tuple[Feature, Binning]],
    boot: GroupBootstrap,
) -> dict[str, FeatureProfile]:
    """Per binned feature, the binned statistics of the (N,) intensity residual `r` and
    dropout residual `d`, with BH q-values over every feature and target together."""
    order = np.argsort(r, kind="stable")  # NaN last; one sort serves every feature's medians
    raw = {}
    for name, (feature, binning) in binnings.items():
        raw[name, "intensity"] = target_stats(r, order, table.is_ground, feature, binning, boot)
        raw[name, "dropout"] = target_stats(d, None, table.is_ground, feature, binning, boot)
    qs = bh_q_values({key: stats_["p_value"] for key, stats_ in raw.items()})
    features = {}
    for name, (feature, binning) in binnings.items():
        per = {t: BinStats(**raw[name, t], q_value=qs[name, t]) for t in TARGETS}
        features[name] = FeatureProfile(
            feature.name,
            feature.title,
            feature.unit,
            feature.ordered,
            binning.labels,
            binning.centres,
            per["intensity"],
            per["dropout"],
        )
    return features


def to_json(loc: Localization) -> dict[str, Any]:
    """The localization as JSON types only (NaN and inf become None)."""
    features = {}
    for name, p in loc.features.items():
        entry: dict[str, Any] = {
            "title": p.title,
            "unit": p.unit,
            "ordered": p.ordered,
            "labels": list(p.labels),
            "centres": p.centres,
        }
        for target in TARGETS:
            s: BinStats = getattr(p, target)
            entry[target] = {f.name: getattr(s, f.name) for f in fields(s)}
        features[name] = entry
    heatmaps = {
        k: {
            "rows": h.rows,
            "cols": h.cols,
            "row_labels": list(h.row_labels),
            "col_labels": list(h.col_labels),
            "mean": h.mean,
            "count": h.count,
        }
        for k, h in loc.heatmaps.items()
    }
    out = {
        "n_rows": loc.n_rows,
        "n_groups": loc.n_groups,
        "n_boot": loc.n_boot,
        "residual_given": loc.residual_given,
        "features": features,
        "statements": loc.statements,
        "heatmaps": heatmaps,
    }
    return dict(json_types(out))


def _heatmap(r: F64, a: Binning, b: Binning, name_a: str, name_b: str) -> Heatmap:
    ka, kb = len(a.labels), len(b.labels)
    ok = (a.index >= 0) & (b.index >= 0) & np.isfinite(r)
    cell = a.index[ok] * kb + b.index[ok]
    count = np.bincount(cell, minlength=ka * kb).reshape(ka, kb).astype(np.int64)
    total = np.bincount(cell, r[ok], minlength=ka * kb).reshape(ka, kb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count >= MIN_HEATMAP_ROWS, total / count, np.nan)
    return Heatmap(name_a, name_b, a.labels, b.labels, mean, count)


# --- statements -------------------------------------------------------------------------

TARGET_WORDS = {"intensity": "ln(I_real/I_sim)", "dropout": "the dropout rate"}


def _statements(features: dict[str, FeatureProfile], limit: int) -> list[dict[str, Any]]:
    out = []
    for target in TARGETS:
        found = [(p, getattr(p, target)) for p in features.values()]
        found = [
            (p, s)
            for p, s in found
            if math.isfinite(s.q_value) and s.q_value < Q_THRESHOLD and math.isfinite(s.effect_size)
        ]
        found.sort(key=lambda ps: -ps[1].effect_size)
        out += [_statement(p, s, target) for p, s in found]
    return out[:limit]


def _statement(p: FeatureProfile, s: BinStats, target: str) -> dict[str, Any]:
    what = TARGET_WORDS[target]
    size = f"{s.effect_size:.2g}"
    if s.direction in ("increases", "decreases"):
        text = f"{what} {s.direction} by {size} from {s.extreme_bins[0]} to {s.extreme_bins[1]}"
        detail = f"cluster-robust slope {s.slope:.2g} per {p.unit}, q = {s.q_value:.1g}"
    else:
        text = f"{what} varies by {size} across {p.title}"
        detail = f"{_lowest_highest(p, s)}; q = {s.q_value:.1g}"
    text = f"{text} ({detail})"
    if s.agreement is not None:
        text += "; " + _agreement_words(s.agreement)
    return {
        "feature": p.name,
        "target": target,
        "bins": list(s.extreme_bins),
        "effect_size": s.effect_size,
        "direction": s.direction,
        "q_value": s.q_value,
        "text": text,
    }


def _lowest_highest(p: FeatureProfile, s: BinStats) -> str:
    share = s.count >= max(MIN_BIN_SHARE * s.count.sum(), 1)
    ok = np.flatnonzero(share & (s.n_groups >= MIN_EFFECT_GROUPS))
    lo, hi = ok[np.argmin(s.mean[ok])], ok[np.argmax(s.mean[ok])]
    return f"lowest {p.labels[lo]}, highest {p.labels[hi]}"


def _agreement_words(a: dict[str, Any]) -> str:
    if a["agree"] is None:
        return "too few ground or non-ground rows to compare them"
    if a["agree"]:
        return "ground and non-ground agree"
    if a["shape_agrees"]:
        return f"ground and non-ground agree in shape, ground offset by {a['offset']:+.2g}"
    n_off = a["compared_bins"] - a["agreeing_bins"]
    return f"ground and non-ground disagree ({n_off} of {a['compared_bins']} bins)"


# --- helpers ----------------------------------------------------------------------------


def _per_row(values: npt.ArrayLike, n: int, name: str) -> F64:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (n,):
        raise InputDataError(
            f"localize: {name} has shape {arr.shape}, the beam table {n} rows; pass one "
            "value per row (NaN where it does not apply)."
        )
    return arr
