"""Where do simulated and real intensities and returns differ? (discovery.md §5.2)

Residuals r = ln(I_real + h) - ln(I_sim + h) (h = half a quantisation step) on beams both
recordings returned, and the dropout indicator d_drop on beams the simulation returned, are
binned by nine features. Per bin: count, mean and median with 95% CIs, and the drop rate
with its CI, all from one cluster bootstrap over `table.group` (groups, never points, are
the independent units: discovery.md §2 item 4).

Tests, per feature and target (intensity, dropout), all cluster-robust over groups:
    omnibus  Wald test that all bin means are equal, over bins with >= 1% of the rows,
             >= MIN_TEST_GROUPS groups (and >= MIN_TEST_EVENTS expected events for 0/1
             outcomes). Covariance: per-bin CR1 sandwich. Reference: F(q, df2) after the
             Welch-James correction from the bins' effective group counts (Welch's ANOVA on
             group totals when groups nest in bins, e.g. scan) and the Hotelling factor
             (G - q) / (G - 1); a plain F(q, G - q) over-rejects when few groups carry a bin.
    trend    (ordered features) OLS slope of y on the row's feature value, CR1 sandwich
             standard error, t with G - 1 degrees of freedom (statsmodels' cluster OLS).
An ordered feature's p-value is the Bonferroni combination min(1, 2 min(p_trend,
p_omnibus)), so both monotone and non-monotone dependence are found; a categorical
feature's is p_omnibus. Benjamini-Hochberg runs over all features x both targets.
On null tables (noise plus a per-group random effect, 120 to 500 groups, 300-400 seeds)
5-6% of tables give any statement at q < 0.05, every single test rejects 3-9% at 0.05.

Median CI: Woodruff's interval (Woodruff 1952, the survey-sampling standard): the cluster
bootstrap SE s of the empirical CDF at the median gives the CI as the bin's quantiles at
0.5 -/+ 1.96 s. Means and drop rates use bootstrap percentile CIs.

The bootstrap draws multinomial group weights once (B x G) and reweights per-group per-bin
sums, so a replicate costs one sparse product instead of a pass over the rows.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import sparse, stats
from statsmodels.stats.multitest import multipletests

from lads.diagnose.table import EDGE_CAP_BEAMS, BeamTable
from lads.errors import InputDataError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

MIN_BIN_SHARE = 0.01  # a bin enters tests and effect sizes with >= 1% of the rows
MIN_EFFECT_GROUPS = 3  # ... and >= 3 groups for the effect size
MIN_TEST_GROUPS = 10  # ... and >= 10 groups for the omnibus test (its variance estimate)
MIN_TEST_EVENTS = 20  # ... and, for 0/1 outcomes, >= 20 expected events (drops, or returns)
MIN_HEATMAP_ROWS = 20
MIN_COMPARE_ROWS = 20  # ground vs non-ground: both sides of a bin need this many rows
AGREE_SHARE = 2.0 / 3.0
Q_THRESHOLD = 0.05
Z95 = 1.959963984540054
DENSE_CELLS = 1 << 22
TARGETS = ("intensity", "dropout")
AGREEMENT_FEATURES = ("range", "cos_incidence")
HEATMAPS = (("range_x_cos", "range", "cos_incidence"), ("ring_x_range", "ring", "range"),
            ("class_x_range", "class", "range"))  # fmt: skip


# --- features (discovery.md §5.2) -------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Binning:
    """One feature's bins on one table.

    Attributes:
        index: (N,) int64 bin of every row; -1 = the row has no value of this feature.
        labels: (K,) bin labels, with units.
        centres: (K,) bin centres in the feature's unit (bin position if categorical).
        value: (N,) the trend variable of an ordered feature (its `unit`), else None.
    """

    index: I64
    labels: tuple[str, ...]
    centres: F64
    value: F64 | None


@dataclass(frozen=True, slots=True)
class Feature:
    """A binned feature: `bin(table)` gives its Binning, or None when it does not apply."""

    name: str
    title: str
    unit: str  # unit of the trend slope ("per m"); "" for categorical features
    ordered: bool
    bin: Callable[[BeamTable], Binning | None]


RANGE_EDGES_M = (0.9, 2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 120.0)
COS_BINS = 10
AZIMUTH_SECTOR_DEG = 10.0
EDGE_EDGES_BEAMS = (0.0, 1.0, 2.0, 3.0, 5.0, 10.0, math.inf)
EDGE_LABELS = ("0 beams", "1 beam", "2 beams", "3-4 beams", "5-9 beams", "10+ beams")


def _edges_bin(values: F64, edges: F64, ok: npt.NDArray[np.bool_]) -> I64:
    """Bin by interior edges; values beyond the outer edges go to the end bins."""
    idx = np.clip(np.searchsorted(edges[1:-1], values, side="right"), 0, edges.size - 2)
    return np.where(ok & np.isfinite(values), idx, -1).astype(np.int64)


def _bin_range(t: BeamTable) -> Binning:
    edges = np.asarray(RANGE_EDGES_M)
    r = t.range_m.astype(np.float64)
    labels = tuple(f"{a:g}-{b:g} m" for a, b in zip(edges[:-1], edges[1:], strict=True))
    return Binning(_edges_bin(r, edges, np.ones(r.size, bool)), labels,
                   np.sqrt(edges[:-1] * edges[1:]), np.clip(r, edges[0], edges[-1]))  # fmt: skip


def _bin_cos(t: BeamTable) -> Binning:
    edges = np.linspace(0.0, 1.0, COS_BINS + 1)
    c = t.cos_incidence.astype(np.float64)
    labels = tuple(f"cos {a:.1f}-{b:.1f}" for a, b in zip(edges[:-1], edges[1:], strict=True))
    return Binning(_edges_bin(c, edges, t.normal_ok), labels, 0.5 * (edges[:-1] + edges[1:]),
                   c)  # fmt: skip


def _categorical(values: npt.NDArray[Any], ok: npt.NDArray[np.bool_], names: Callable[[int], str]
                 ) -> Binning:  # fmt: skip
    present = np.unique(values[ok])
    idx = np.where(ok, np.searchsorted(present, values), -1).astype(np.int64)
    return Binning(idx, tuple(names(int(v)) for v in present),
                   np.arange(present.size, dtype=np.float64), None)  # fmt: skip


def _bin_class(t: BeamTable) -> Binning | None:
    known = t.class_id >= 0
    if not known.any():
        return None
    return _categorical(t.class_id, known, lambda c: t.class_names.get(c, f"class {c}"))


def _bin_ring(t: BeamTable) -> Binning:
    return _categorical(t.ring, np.ones(len(t), bool), lambda k: f"ring {k}")


def _bin_azimuth(t: BeamTable) -> Binning:
    n = int(round(360.0 / AZIMUTH_SECTOR_DEG))
    az = np.mod(t.azimuth_deg.astype(np.float64), 360.0)
    idx = np.clip(np.floor(az / AZIMUTH_SECTOR_DEG), 0, n - 1)
    idx = np.where(np.isfinite(az), idx, -1).astype(np.int64)
    labels = tuple(f"{i * AZIMUTH_SECTOR_DEG:g}-{(i + 1) * AZIMUTH_SECTOR_DEG:g} deg"
                   for i in range(n))  # fmt: skip
    return Binning(idx, labels, (np.arange(n) + 0.5) * AZIMUTH_SECTOR_DEG, None)


def _bin_i_sim(t: BeamTable) -> Binning | None:
    v = t.i_sim.astype(np.float64)
    ok = t.ret_sim & np.isfinite(v)
    if not ok.any():
        return None
    edges = np.unique(np.quantile(v[ok], np.linspace(0.0, 1.0, 11)))
    if edges.size < 2:
        edges = np.array([edges[0], edges[0]])
    labels = tuple(f"I_sim {a:.3g}-{b:.3g}" for a, b in zip(edges[:-1], edges[1:], strict=True))
    return Binning(_edges_bin(v, edges, ok), labels, 0.5 * (edges[:-1] + edges[1:]), v)


def _bin_edge(t: BeamTable) -> Binning:
    e = np.minimum(t.edge_beams.astype(np.float64), EDGE_CAP_BEAMS)
    edges = np.asarray(EDGE_EDGES_BEAMS)
    centres = np.array([0.0, 1.0, 2.0, 3.5, 7.0, EDGE_CAP_BEAMS])
    return Binning(_edges_bin(e, edges, np.ones(e.size, bool)), EDGE_LABELS, centres, e)


def _bin_ground(t: BeamTable) -> Binning:
    return Binning(t.is_ground.astype(np.int64), ("non-ground", "ground"),
                   np.array([0.0, 1.0]), None)  # fmt: skip


def _bin_scan(t: BeamTable) -> Binning:
    k = max(len(t.scans), int(t.scan.max(initial=-1)) + 1)
    labels = tuple(t.scans[i] if i < len(t.scans) else f"scan {i}" for i in range(k))
    return Binning(t.scan.astype(np.int64), labels, np.arange(k, dtype=np.float64), None)


FEATURES: tuple[Feature, ...] = (
    Feature("range", "range", "m", True, _bin_range),
    Feature("cos_incidence", "cos(incidence)", "unit of cos(theta)", True, _bin_cos),
    Feature("class", "class", "", False, _bin_class),
    Feature("ring", "ring", "", False, _bin_ring),
    Feature("azimuth", "azimuth sector", "", False, _bin_azimuth),
    Feature("i_sim_decile", "I_sim decile", "stored unit of I_sim", True, _bin_i_sim),
    Feature("edge_distance", "distance to a range edge", "beam", True, _bin_edge),
    Feature("ground", "ground vs non-ground", "", False, _bin_ground),
    Feature("scan", "scan", "", False, _bin_scan),
)
"""The features of discovery.md §5.2, in report order."""


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
    """r, d_drop and d_extra of every row (discovery.md §5.2).

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
    groups, gid = np.unique(table.group, return_inverse=True)
    n_groups = groups.size
    weights = rng.multinomial(n_groups, np.full(n_groups, 1.0 / n_groups), size=n_boot)
    boot = _Boot(gid.astype(np.int64), n_groups, np.ascontiguousarray(weights.T, np.float64))

    binnings: dict[str, tuple[Feature, Binning]] = {}
    for feature in FEATURES:
        binning = feature.bin(table)
        if binning is not None:
            binnings[feature.name] = (feature, binning)
    order = np.argsort(r, kind="stable")  # NaN last; one sort serves every feature's medians
    raw = {}
    for name, (feature, binning) in binnings.items():
        raw[name, "intensity"] = _target_stats(r, order, table.is_ground, feature, binning, boot)
        raw[name, "dropout"] = _target_stats(d, None, table.is_ground, feature, binning, boot)
    qs = _bh({key: stats_["p_value"] for key, stats_ in raw.items()})
    features = {}
    for name, (feature, binning) in binnings.items():
        per = {t: BinStats(**raw[name, t], q_value=qs[name, t]) for t in TARGETS}
        features[name] = FeatureProfile(feature.name, feature.title, feature.unit,
                                        feature.ordered, binning.labels, binning.centres,
                                        per["intensity"], per["dropout"])  # fmt: skip
    heatmaps = {
        key: _heatmap(r, binnings[a][1], binnings[b][1], a, b)
        for key, a, b in HEATMAPS
        if a in binnings and b in binnings
    }
    return Localization(features, _statements(features, max_statements), heatmaps, n,
                        n_groups, n_boot, residual is not None)  # fmt: skip


def to_json(loc: Localization) -> dict[str, Any]:
    """The localization as JSON types only (NaN and inf become None)."""
    features = {}
    for name, p in loc.features.items():
        entry: dict[str, Any] = {"title": p.title, "unit": p.unit, "ordered": p.ordered,
                                 "labels": list(p.labels), "centres": p.centres}  # fmt: skip
        for target in TARGETS:
            s: BinStats = getattr(p, target)
            entry[target] = {f.name: getattr(s, f.name) for f in fields(s)}
        features[name] = entry
    heatmaps = {k: {"rows": h.rows, "cols": h.cols, "row_labels": list(h.row_labels),
                    "col_labels": list(h.col_labels), "mean": h.mean, "count": h.count}
                for k, h in loc.heatmaps.items()}  # fmt: skip
    out = {"n_rows": loc.n_rows, "n_groups": loc.n_groups, "n_boot": loc.n_boot,
           "residual_given": loc.residual_given, "features": features,
           "statements": loc.statements, "heatmaps": heatmaps}  # fmt: skip
    return dict(json_safe(out))


# --- binned statistics -----------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Boot:
    gid: I64  # (N,) compressed group of every row
    n_groups: int
    weights_t: F64  # (G, B) multinomial group weights

    def sums(self, rows: I64, bins: I64, k: int, columns: list[F64]) -> tuple[I64, list[F64]]:
        """Per (group, bin) cell: cell ids g * k + bin and the column sums."""
        cell = self.gid[rows] * k + bins
        size = self.n_groups * k
        if size <= DENSE_CELLS:
            cells = np.flatnonzero(np.bincount(cell, minlength=size)).astype(np.int64)
            return cells, [np.bincount(cell, c, minlength=size)[cells].astype(np.float64)
                           for c in columns]  # fmt: skip
        cells, inv = np.unique(cell, return_inverse=True)
        return cells, [np.bincount(inv, c, minlength=cells.size).astype(np.float64)
                       for c in columns]  # fmt: skip

    def replicate(self, cells: I64, k: int, values: F64) -> F64:
        """(k, B) per-bin totals of `values` (one per cell) under every replicate."""
        m = sparse.csr_matrix((values, (cells % k, cells // k)), shape=(k, self.n_groups))
        return np.asarray(m @ self.weights_t)


def _target_stats(
    y_all: F64, order: I64 | None, ground: npt.NDArray[np.bool_], feature: Feature,
    binning: Binning, boot: _Boot,
) -> dict[str, Any]:  # fmt: skip
    """Binned statistics and tests of y_all; medians when `order` (argsort of y_all) is given."""
    k = len(binning.labels)
    rows = np.flatnonzero((binning.index >= 0) & np.isfinite(y_all)).astype(np.int64)
    y, bins = y_all[rows], binning.index[rows]
    count = np.bincount(bins, minlength=k).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(bins, y, minlength=k) / count
    sorted_y = None if order is None else _sorted_by_bin(y_all, order, rows, binning.index, k)
    median, z = np.full(k, np.nan), None
    if sorted_y is not None:
        median, z = _medians(sorted_y, y, bins, count)
    cols = [np.ones(rows.size), y] + ([z] if z is not None else [])
    cells, sums = boot.sums(rows, bins, k, cols)
    n_groups = np.bincount(cells % k, minlength=k).astype(np.int64)
    rep_n = boot.replicate(cells, k, sums[0])
    with np.errstate(invalid="ignore", divide="ignore"):
        rep_mean = boot.replicate(cells, k, sums[1]) / rep_n
        rep_z = boot.replicate(cells, k, sums[2]) / rep_n if z is not None else None
    mean_low, mean_high = _percentiles(rep_mean)
    med_low, med_high = (median, median)
    if sorted_y is not None and rep_z is not None:
        med_low, med_high = _woodruff(sorted_y, count, rep_z)
    share = count >= max(MIN_BIN_SHARE * rows.size, 1)
    effect_bins = np.flatnonzero(share & (n_groups >= MIN_EFFECT_GROUPS))
    testable = share & (n_groups >= MIN_TEST_GROUPS)
    if np.all((y == 0) | (y == 1)):  # rare binary outcomes: normal theory needs events
        rate = float(y.mean())
        testable &= np.minimum(rate, 1 - rate) * count >= MIN_TEST_EVENTS
    test_bins = np.flatnonzero(testable)
    p_omnibus = _wald_equal_means(cells, sums[1], sums[0], mean, count, test_bins, k)
    slope = slope_se = p_trend = math.nan
    if feature.ordered and binning.value is not None:
        x = binning.value[rows]
        slope, slope_se, p_trend = _cluster_slope(x, y, boot.gid[rows], boot.n_groups)
    p_value = p_omnibus
    if feature.ordered:
        finite = [p for p in (p_trend, p_omnibus) if math.isfinite(p)]
        p_value = min(1.0, 2.0 * min(finite)) if finite else math.nan
    effect, extremes, direction = _effect(mean, effect_bins, binning.labels, feature.ordered,
                                          slope, p_trend)  # fmt: skip
    agreement = None
    if feature.name in AGREEMENT_FEATURES:
        agreement = _agreement(y, bins, rows, ground[rows], k, boot)
    return dict(count=count, n_groups=n_groups, mean=mean, mean_low=mean_low,
                mean_high=mean_high, median=median, median_low=med_low, median_high=med_high,
                p_value=p_value, p_trend=p_trend, p_omnibus=p_omnibus, effect_size=effect,
                extreme_bins=extremes, slope=slope, slope_se=slope_se, direction=direction,
                agreement=agreement)  # fmt: skip


def _sorted_by_bin(y_all: F64, order: I64, rows: I64, index: I64, k: int) -> F64:
    """y of `rows`, grouped by bin (bins ascending) and sorted within each bin."""
    valid = np.zeros(y_all.size, dtype=bool)
    valid[rows] = True
    by_value = order[valid[order]]
    bins = index[by_value]
    small = bins.astype(np.int16) if k < np.iinfo(np.int16).max else bins  # radix sort
    sorted_y: F64 = y_all[by_value[np.argsort(small, kind="stable")]]
    return sorted_y


def _medians(sorted_y: F64, y: F64, bins: I64, count: I64) -> tuple[F64, F64]:
    """Per-bin medians and the row indicator y <= median of its bin."""
    median = _sorted_quantile(sorted_y, count, np.full(count.size, 0.5))
    return median, (y <= median[bins]).astype(np.float64)


def _woodruff(sorted_y: F64, count: I64, rep_z: F64) -> tuple[F64, F64]:
    se = _nanstd(rep_z)
    low = _sorted_quantile(sorted_y, count, np.clip(0.5 - Z95 * se, 0.0, 1.0))
    high = _sorted_quantile(sorted_y, count, np.clip(0.5 + Z95 * se, 0.0, 1.0))
    return low, high


def _sorted_quantile(sorted_y: F64, count: I64, level: F64) -> F64:
    """Linear-interpolated quantile `level` of each bin's segment of `sorted_y`."""
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    ok = (count > 0) & np.isfinite(level)
    pos = np.where(ok, level, 0.0) * np.maximum(count - 1, 0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(count - 1, 0))
    frac = pos - lo
    n = max(sorted_y.size - 1, 0)
    a = sorted_y[np.minimum(start + lo, n)] if sorted_y.size else np.zeros(count.size)
    b = sorted_y[np.minimum(start + hi, n)] if sorted_y.size else np.zeros(count.size)
    return np.where(ok, a + frac * (b - a), np.nan)


def _percentiles(rep: F64) -> tuple[F64, F64]:
    """2.5 and 97.5 percentiles over replicates (axis 1), NaN when half are undefined."""
    finite = np.isfinite(rep)
    enough = finite.sum(axis=1) >= max(rep.shape[1] // 2, 1)
    srt = np.sort(np.where(finite, rep, np.inf), axis=1)  # undefined replicates sort last
    n_ok = finite.sum(axis=1)
    out = []
    for q in (0.025, 0.975):
        pos = q * np.maximum(n_ok - 1, 0)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, np.maximum(n_ok - 1, 0))
        a = np.take_along_axis(srt, lo[:, None], axis=1)[:, 0]
        b = np.take_along_axis(srt, hi[:, None], axis=1)[:, 0]
        with np.errstate(invalid="ignore"):
            out.append(np.where(enough, a + (pos - lo) * (b - a), np.nan))
    return out[0], out[1]


def _nanstd(rep: F64) -> F64:
    finite = np.isfinite(rep)
    n = finite.sum(axis=1)
    x = np.where(finite, rep, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = x.sum(axis=1) / n
        var = (np.where(finite, rep - mu[:, None], 0.0) ** 2).sum(axis=1) / (n - 1)
    return np.where(n >= 2, np.sqrt(var), np.nan)


def _wald_equal_means(
    cells: I64, sum_y: F64, n_cell: F64, mean: F64, count: I64, test_bins: I64, k: int
) -> float:
    """Cluster-robust Wald test that the means of `test_bins` are equal.

    Each bin's influence column gets its own CR1 factor G_k / (G_k - 1). Bins seen by few
    groups make the covariance noisy, which a plain F(q, G - q) reference ignores (a CRVE
    over-rejects when few clusters carry a dummy): the statistic gets the Welch-James
    correction computed from the per-bin effective group counts G_k (exactly Welch's ANOVA on group
    totals when groups nest in bins), and the Hotelling factor (G - q) / (G - 1).
    """
    if test_bins.size < 2:
        return math.nan
    position = np.full(k, -1, dtype=np.int64)
    position[test_bins] = np.arange(test_bins.size)
    pos = position[cells % k]
    keep = pos >= 0
    kb = cells[keep] % k
    # Kish's effective number of groups per bin, n_k^2 / sum_g n_gk^2: groups that hold
    # a handful of a bin's rows do not count as whole clusters.
    g_k = count[test_bins] ** 2 / np.bincount(pos[keep], n_cell[keep] ** 2, test_bins.size)
    g_k = np.maximum(g_k, 2.0)
    influence = (sum_y[keep] - n_cell[keep] * mean[kb]) / count[kb]
    influence *= np.sqrt(g_k / (g_k - 1))[pos[keep]]
    groups, g = np.unique(cells[keep] // k, return_inverse=True)
    n_g = groups.size
    s = sparse.csr_matrix((influence, (g, pos[keep])), shape=(n_g, test_bins.size))
    v = (s.T @ s).toarray()
    m = mean[test_bins]
    diff = m[:-1] - m[-1]
    cvc = v[:-1, :-1] - v[:-1, -1:] - v[-1:, :-1] + v[-1, -1]
    w, u = np.linalg.eigh(cvc)
    top = float(w.max()) if w.size else 0.0
    keep_w = w > 1e-10 * top if top > 0 else np.zeros(w.size, dtype=bool)
    q = int(keep_w.sum())
    variances = np.diag(v)
    if q == 0 or n_g <= q or np.any(variances <= 0):
        return math.nan
    wald = float(np.sum((u[:, keep_w].T @ diff) ** 2 / w[keep_w]))
    bins = test_bins.size
    weights = 1.0 / variances
    h = float(np.sum((1.0 - weights / weights.sum()) ** 2 / (g_k - 1.0)))
    welch = 1.0 + 2.0 * (bins - 2.0) / (bins**2 - 1.0) * h
    df2 = min((bins**2 - 1.0) / (3.0 * h), float(n_g - q))
    f_stat = wald / (q * welch) * (n_g - q) / (n_g - 1)
    return float(stats.f.sf(f_stat, q, df2))


def _cluster_slope(x: F64, y: F64, gid: I64, n_all: int) -> tuple[float, float, float]:
    """OLS slope of y on x, CR1 cluster-robust SE over groups, two-sided t(G - 1) p."""
    n = x.size
    n_g = int(np.count_nonzero(np.bincount(gid, minlength=n_all)))
    if n < 3 or n_g < 3:
        return math.nan, math.nan, math.nan
    xc = x - x.mean()
    sxx = float(xc @ xc)
    if sxx <= 0:
        return math.nan, math.nan, math.nan
    slope = float(xc @ y) / sxx
    e = y - y.mean() - slope * xc
    score = np.bincount(gid, xc * e, minlength=n_all)
    correction = n_g / (n_g - 1) * (n - 1) / (n - 2)
    se = math.sqrt(correction * float(score @ score)) / sxx
    if se == 0:
        return slope, se, math.nan
    return slope, se, float(2.0 * stats.t.sf(abs(slope / se), n_g - 1))


def _effect(
    mean: F64, eligible: I64, labels: tuple[str, ...], ordered: bool, slope: float,
    p_trend: float,
) -> tuple[float, tuple[str, ...], str]:  # fmt: skip
    if eligible.size < 2:
        return math.nan, (), "varies"
    m = mean[eligible]
    lo, hi = int(eligible[np.argmin(m)]), int(eligible[np.argmax(m)])
    extremes = tuple(labels[i] for i in sorted((lo, hi)))
    direction = "varies"
    if ordered and math.isfinite(p_trend) and p_trend < Q_THRESHOLD:
        rising = hi > lo
        if (slope > 0) == rising:
            direction = "increases" if rising else "decreases"
    return float(m.max() - m.min()), extremes, direction


def _agreement(
    y: F64, bins: I64, rows: I64, ground: npt.NDArray[np.bool_], k: int, boot: _Boot
) -> dict[str, Any]:
    """Ground vs non-ground per-bin means: same shape (after a level offset) and level?"""
    split = bins + k * ground.astype(np.int64)  # non-ground bins 0..k-1, ground k..2k-1
    count = np.bincount(split, minlength=2 * k)
    cells, (n_cell, s_cell) = boot.sums(rows, split, 2 * k, [np.ones(y.size), y])
    with np.errstate(invalid="ignore", divide="ignore"):
        point = np.bincount(split, y, minlength=2 * k) / count
        rep = boot.replicate(cells, 2 * k, s_cell) / boot.replicate(cells, 2 * k, n_cell)
    both = np.flatnonzero((count[:k] >= MIN_COMPARE_ROWS) & (count[k:] >= MIN_COMPARE_ROWS))
    out: dict[str, Any] = {"compared_bins": int(both.size), "agreeing_bins": 0, "agree": None,
                           "shape_agrees": None, "offset": math.nan, "offset_low": math.nan,
                           "offset_high": math.nan}  # fmt: skip
    if both.size < 2:
        return out
    w = (count[both] + count[k + both]).astype(np.float64)
    w /= w.sum()

    def centred(values: F64) -> tuple[F64, F64]:
        diff = values[k + both] - values[both]  # ground - non-ground, per compared bin
        offset = np.tensordot(w, diff, axes=(0, 0))
        return diff - offset, offset

    shape_point, offset_point = centred(point)
    shape_rep, offset_rep = centred(rep)
    low, high = _percentiles(shape_rep)
    agreeing = int(np.sum((low <= 0) & (high >= 0)))
    off_low, off_high = _percentiles(np.atleast_2d(offset_rep))
    shape_ok = agreeing >= AGREE_SHARE * both.size
    level_ok = bool(off_low[0] <= 0 <= off_high[0])
    out.update(agreeing_bins=agreeing, shape_agrees=bool(shape_ok),
               agree=bool(shape_ok and level_ok), offset=float(offset_point),
               offset_low=float(off_low[0]), offset_high=float(off_high[0]))  # fmt: skip
    return out


def _bh(pvals: dict[tuple[str, str], float]) -> dict[tuple[str, str], float]:
    keys = [k for k, p in pvals.items() if math.isfinite(p)]
    out = {k: math.nan for k in pvals}
    if keys:
        q = multipletests([pvals[k] for k in keys], method="fdr_bh")[1]
        out.update({k: float(v) for k, v in zip(keys, q, strict=True)})
    return out


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
        found = [(p, s) for p, s in found
                 if math.isfinite(s.q_value) and s.q_value < Q_THRESHOLD
                 and math.isfinite(s.effect_size)]  # fmt: skip
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
    return {"feature": p.name, "target": target, "bins": list(s.extreme_bins),
            "effect_size": s.effect_size, "direction": s.direction, "q_value": s.q_value,
            "text": text}  # fmt: skip


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


def json_safe(value: Any) -> Any:
    """JSON types only: numpy unwrapped, tuples as lists, NaN/inf as None."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        return json_safe(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value
