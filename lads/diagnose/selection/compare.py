"""Held-out comparisons of two fits: per-row gains, cluster standard errors over spatial
groups, and the directional score a candidate is accepted on (docs/diagnose.md §5.5)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.diagnose.fit.design import Design, group_index
from lads.diagnose.fit.likelihood import RowTerms
from lads.diagnose.fit.model import Fit, directional_gain


@dataclass(frozen=True)
class Comparison:
    """Held-out comparison of a candidate model with the incumbent (positive = better).

    delta, se: mean per-row NLL gain and its SE; score, score_se: mean per-row directional
    gain (`model.directional_gain`) and its SE, the test statistic (`z`)."""

    delta: float
    se: float
    delta_bic: float
    groups: int = 0
    score: float = 0.0
    score_se: float = math.inf

    @property
    def z(self) -> float:
        return self.score / self.score_se if self.score_se > 0 else 0.0


def compare(
    new: Fit, old: Fit, d: Design, rows: npt.NDArray[np.int64], n_eff_scale: float, n_fit: float
) -> Comparison:
    """Mean per-row NLL gain on `rows` with its cluster SE, and the training delta-BIC."""
    return compare_on(new, old, d.subset(rows), n_eff_scale, n_fit)


@dataclass(frozen=True)
class Incumbent:
    """A model's per-row NLL and likelihood terms on held-out rows (cut once, compare often)."""

    nll: npt.NDArray[np.float64]
    terms: RowTerms

    @classmethod
    def of(cls, f: Fit, sub: Design) -> Incumbent:
        terms = f.row_terms(sub)
        return cls(terms.nll(sub), terms)


def compare_on(
    new: Fit,
    old: Fit,
    sub: Design,
    n_eff_scale: float,
    n_fit: float,
    incumbent: Incumbent | None = None,
) -> Comparison:
    """`compare` on held-out rows already cut out of the design, with the directional score.

    `incumbent`: `Incumbent.of(old, sub)` when already computed (one incumbent, many
    candidates)."""
    n_eff = max(n_fit * n_eff_scale, 2.0)
    dk = new.model.size - old.model.size
    delta_bic = 2.0 * (new.loss - old.loss) * n_eff + dk * math.log(n_eff)
    return by_rows(
        *row_gains(new, old, sub, incumbent), sub.group, float(delta_bic), index=sub.group_index
    )


def row_gains(
    new: Fit, old: Fit, sub: Design, incumbent: Incumbent | None = None
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(N,) per-row NLL gain and directional score of `new` over `old` (positive = better)."""
    inc = incumbent if incumbent is not None else Incumbent.of(old, sub)
    end = new.row_terms(sub)
    return inc.nll - end.nll(sub), directional_gain(inc.terms, end, sub)


def gain_on(new: Fit, old: Fit, sub: Design) -> Comparison:
    """The held-out NLL gain alone (no score): for models that are not nested, where only
    "which predicts better" is asked (the one-SE rule, ambiguity sets)."""
    return by_rows(old.row_nll(sub) - new.row_nll(sub), None, sub.group, index=sub.group_index)


def by_rows(
    gain: npt.NDArray[np.float64],
    score: npt.NDArray[np.float64] | None,
    group: npt.NDArray[np.int64],
    delta_bic: float = 0.0,
    *,
    index: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]] | None = None,
) -> Comparison:
    """Per-row means of the gain and the score with their cluster (ratio-estimator) SEs;
    `index`: `group_index(group)` when already known (`Design.group_index`)."""
    inv, g_n = index if index is not None else group_index(group)
    total, k = g_n.sum(), len(g_n)

    def mean_se(rows: npt.NDArray[np.float64]) -> tuple[float, float]:
        g_sum = np.bincount(inv, weights=rows)
        mean = float(g_sum.sum() / total)
        return mean, math.sqrt(k / max(k - 1, 1) * float(((g_sum - mean * g_n) ** 2).sum())) / total

    if score is None:
        return Comparison(*mean_se(gain), delta_bic, k)
    return Comparison(*mean_se(gain), delta_bic, k, *mean_se(score))


def compare_groups(new: Fit, old: Fit, sub: Design) -> Comparison:
    """`by_groups` of `new` over `old` on the held-out rows `sub` of a class."""
    return by_groups(old.row_nll(sub) - new.row_nll(sub), sub.group, index=sub.group_index)


def by_groups(
    gain: npt.NDArray[np.float64],
    group: npt.NDArray[np.int64],
    *,
    index: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]] | None = None,
) -> Comparison:
    """Mean over groups of each group's mean per-row gain, with its SE over groups.

    The test of a class-confined effect on its own rows. Every group (an independent surface,
    docs/diagnose.md §2 item 4) counts once: the row-weighted ratio of `by_rows` lets the
    spread of group sizes (1 to 24 sign rows per tile) and of the gain itself (a retro gain
    clipped at the encoding's top in some tiles, not in others) swamp a gain that is positive
    in every group, and lets one large tile carry a chance gain on a null case. `index` as
    in `by_rows`."""
    inv, g_n = index if index is not None else group_index(group)
    k = len(g_n)
    means = np.bincount(inv, weights=gain) / g_n
    se = float(np.std(means, ddof=1)) / math.sqrt(k) if k > 1 else math.inf
    return Comparison(float(means.mean()), se, 0.0, k)


def design_effect_scale(d: Design, rows: npt.NDArray[np.int64]) -> float:
    """n_eff / n from the intra-group correlation of the baseline residual (Kish)."""
    ret = d.fits_intensity[rows]
    r = (d.y.numpy() - d.ln_sim.numpy())[rows][ret]
    g = d.group[rows][ret]
    if r.size < 10:
        return 1.0
    _, inv = np.unique(g, return_inverse=True)
    n_g = np.bincount(inv).astype(np.float64)
    means = np.bincount(inv, weights=r) / n_g
    within = float(((r - means[inv]) ** 2).sum()) / max(r.size - len(n_g), 1)
    between = float((n_g * (means - r.mean()) ** 2).sum()) / max(len(n_g) - 1, 1)
    m = r.size / len(n_g)
    var_between = max((between - within) / m, 0.0)
    icc = var_between / max(var_between + within, 1e-12)
    return 1.0 / (1.0 + (m - 1.0) * icc)
