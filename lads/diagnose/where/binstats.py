"""Cluster-bootstrap statistics and tests of one target binned by one feature.

The building blocks of `lads.diagnose.where.localize` (docs/diagnose.md §5.2). Groups
(`table.group`), never points, are the independent units (docs/diagnose.md §2 item 4).

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
feature's is p_omnibus. Benjamini-Hochberg (`bh_q_values`) runs over all features x both
targets. On null tables (noise plus a per-group random effect, 120 to 500 groups, 300-400
seeds) 5-6% of tables give any statement at q < 0.05, every single test rejects 3-9% at 0.05.

Median CI: Woodruff's interval (Woodruff 1952, the survey-sampling standard): the cluster
bootstrap SE s of the empirical CDF at the median gives the CI as the bin's quantiles at
0.5 -/+ 1.96 s. Means and drop rates use bootstrap percentile CIs.

The bootstrap draws multinomial group weights once (B x G) and reweights per-group per-bin
sums, so a replicate costs one sparse product instead of a pass over the rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import sparse, stats
from statsmodels.stats.multitest import multipletests

from lads.diagnose.config import CONFIG
from lads.diagnose.where.binning import F64, I64, Binning, Feature

MIN_BIN_SHARE = CONFIG.localize.min_bin_share
MIN_EFFECT_GROUPS = CONFIG.localize.min_effect_groups
MIN_TEST_GROUPS = CONFIG.localize.min_test_groups
MIN_TEST_EVENTS = CONFIG.localize.min_test_events
MIN_COMPARE_ROWS = CONFIG.localize.min_compare_rows
AGREE_SHARE = CONFIG.localize.agree_share
Q_THRESHOLD = CONFIG.localize.q_threshold
Z95 = 1.959963984540054
DENSE_CELLS = 1 << 22
AGREEMENT_FEATURES = ("range", "cos_incidence")


@dataclass(frozen=True, slots=True)
class GroupBootstrap:
    """Cluster bootstrap over groups: multinomial group weights, drawn once."""

    gid: I64  # (N,) compressed group of every row
    n_groups: int
    weights_t: F64  # (G, B) multinomial group weights

    def sums(self, rows: I64, bins: I64, k: int, columns: list[F64]) -> tuple[I64, list[F64]]:
        """Per (group, bin) cell: cell ids g * k + bin and the column sums."""
        cell = self.gid[rows] * k + bins
        size = self.n_groups * k
        if size <= DENSE_CELLS:
            cells = np.flatnonzero(np.bincount(cell, minlength=size)).astype(np.int64)
            return cells, [
                np.bincount(cell, c, minlength=size)[cells].astype(np.float64) for c in columns
            ]
        cells, inv = np.unique(cell, return_inverse=True)
        return cells, [
            np.bincount(inv, c, minlength=cells.size).astype(np.float64) for c in columns
        ]

    def replicate(self, cells: I64, k: int, values: F64) -> F64:
        """(k, B) per-bin totals of `values` (one per cell) under every replicate."""
        m = sparse.csr_matrix((values, (cells % k, cells // k)), shape=(k, self.n_groups))
        return np.asarray(m @ self.weights_t)


def target_stats(
    y_all: F64,
    order: I64 | None,
    ground: npt.NDArray[np.bool_],
    feature: Feature,
    binning: Binning,
    boot: GroupBootstrap,
) -> dict[str, Any]:
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
    effect_bins, test_bins = _usable_bins(y, count, n_groups)
    p_omnibus = _wald_equal_means(cells, sums[1], sums[0], mean, count, test_bins, k)
    slope, slope_se, p_trend, p_value = _trend_test(feature, binning, rows, y, boot, p_omnibus)
    effect, extremes, direction = _effect(
        mean, effect_bins, binning.labels, feature.ordered, slope, p_trend
    )
    agreement = None
    if feature.name in AGREEMENT_FEATURES:
        agreement = _agreement(y, bins, rows, ground[rows], k, boot)
    return dict(
        count=count,
        n_groups=n_groups,
        mean=mean,
        mean_low=mean_low,
        mean_high=mean_high,
        median=median,
        median_low=med_low,
        median_high=med_high,
        p_value=p_value,
        p_trend=p_trend,
        p_omnibus=p_omnibus,
        effect_size=effect,
        extreme_bins=extremes,
        slope=slope,
        slope_se=slope_se,
        direction=direction,
        agreement=agreement,
    )


def _usable_bins(y: F64, count: I64, n_groups: I64) -> tuple[I64, I64]:
    """The bins with enough rows and groups to report an effect, and those (with enough
    events, for a binary y) to test; both as bin indices."""
    share = count >= max(MIN_BIN_SHARE * y.size, 1)
    effect_bins = np.flatnonzero(share & (n_groups >= MIN_EFFECT_GROUPS))
    testable = share & (n_groups >= MIN_TEST_GROUPS)
    if y.size and np.all((y == 0) | (y == 1)):  # rare binary outcomes: need events
        rate = float(y.mean())
        testable &= np.minimum(rate, 1 - rate) * count >= MIN_TEST_EVENTS
    return effect_bins, np.flatnonzero(testable)


def _trend_test(
    feature: Feature, binning: Binning, rows: I64, y: F64, boot: GroupBootstrap, p_omnibus: float
) -> tuple[float, float, float, float]:
    """(slope, its SE, trend p-value, the feature's p-value): for an ordered feature the
    cluster-robust slope of y on the bin value, and the Bonferroni pair of trend and
    omnibus tests; otherwise NaNs and the omnibus p-value."""
    slope = slope_se = p_trend = math.nan
    if feature.ordered and binning.value is not None:
        x = binning.value[rows]
        slope, slope_se, p_trend = _cluster_slope(x, y, boot.gid[rows], boot.n_groups)
    p_value = p_omnibus
    if feature.ordered:
        finite = [p for p in (p_trend, p_omnibus) if math.isfinite(p)]
        p_value = min(1.0, 2.0 * min(finite)) if finite else math.nan
    return slope, slope_se, p_trend, p_value


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
    mean: F64,
    eligible: I64,
    labels: tuple[str, ...],
    ordered: bool,
    slope: float,
    p_trend: float,
) -> tuple[float, tuple[str, ...], str]:
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
    y: F64, bins: I64, rows: I64, ground: npt.NDArray[np.bool_], k: int, boot: GroupBootstrap
) -> dict[str, Any]:
    """Ground vs non-ground per-bin means: same shape (after a level offset) and level?"""
    split = bins + k * ground.astype(np.int64)  # non-ground bins 0..k-1, ground k..2k-1
    count = np.bincount(split, minlength=2 * k)
    cells, (n_cell, s_cell) = boot.sums(rows, split, 2 * k, [np.ones(y.size), y])
    with np.errstate(invalid="ignore", divide="ignore"):
        point = np.bincount(split, y, minlength=2 * k) / count
        rep = boot.replicate(cells, 2 * k, s_cell) / boot.replicate(cells, 2 * k, n_cell)
    both = np.flatnonzero((count[:k] >= MIN_COMPARE_ROWS) & (count[k:] >= MIN_COMPARE_ROWS))
    out: dict[str, Any] = {
        "compared_bins": int(both.size),
        "agreeing_bins": 0,
        "agree": None,
        "shape_agrees": None,
        "offset": math.nan,
        "offset_low": math.nan,
        "offset_high": math.nan,
    }
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
    out.update(
        agreeing_bins=agreeing,
        shape_agrees=bool(shape_ok),
        agree=bool(shape_ok and level_ok),
        offset=float(offset_point),
        offset_low=float(off_low[0]),
        offset_high=float(off_high[0]),
    )
    return out


def bh_q_values(pvals: dict[tuple[str, str], float]) -> dict[tuple[str, str], float]:
    """Benjamini-Hochberg q of every finite p-value (NaN p-values stay NaN)."""
    keys = [k for k, p in pvals.items() if math.isfinite(p)]
    out = {k: math.nan for k in pvals}
    if keys:
        q = multipletests([pvals[k] for k in keys], method="fdr_bh")[1]
        out.update({k: float(v) for k, v in zip(keys, q, strict=True)})
    return out
