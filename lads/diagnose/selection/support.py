"""A candidate's support: the held-out rows it acts on (its class, or the domain its own fit
chose) and, for a class held by few held-out groups, the training groups that hold it, each
scored out of sample (docs/diagnose.md §5.5)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import stats

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.base import Effect
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.model import Fit, fit
from lads.diagnose.selection.compare import Comparison, by_groups

# A class-confined effect (a glossy car, a retro-reflecting sign) changes only that class's
# rows, which sit in a few groups. Its gain averaged over every held-out group has a cluster
# SE dominated by the untouched groups, so z cannot exceed ~sqrt(groups with the class)
# however consistent the gain is: six signs could never pass z >= 3. It is therefore also
# tested on its own rows: the mean over groups of each group's mean gain (`compare_groups`),
# with Student's t at the same one-sided tail as the z bar (df = groups - 1: few groups need
# a much larger ratio), provided its gain over all held-out rows is positive. At least
# MIN_SUPPORT_GROUPS groups must hold the class.
MIN_SUPPORT_GROUPS = CONFIG.select.min_support_groups
# A class whose held-out support has fewer than CROSSFIT_BELOW_GROUPS groups is also scored
# on the training groups that hold it, each out of sample: the training groups are split in
# CROSSFIT_FOLDS folds and both the incumbent and the candidate are refitted without each
# fold (`crossfit_support`). A class in a handful of held-out tiles (a few retro-reflecting
# signs) can gain strongly there yet miss a t bar with so few degrees of freedom, while the
# training tiles hold more of it that no test reads. Only candidates that already pass the
# resamples' bar on their held-out groups are cross-fitted (the refits cost 2 x
# CROSSFIT_FOLDS fits each).
CROSSFIT_BELOW_GROUPS = CONFIG.select.crossfit_below_groups
CROSSFIT_FOLDS = CONFIG.select.crossfit_folds
Z_RESAMPLE = CONFIG.select.z_resample  # the bar a cross-fitted candidate must pass first


def crossfit_support(
    new: Fit,
    old: Fit,
    d: Design,
    weights: npt.NDArray[np.float64],
    sub: Design,
    class_index: int,
    refs: dict[bytes, Fit],
) -> Comparison:
    """`compare_groups` on the held-out class rows `sub` pooled with the class rows of the
    training groups, each scored by `new` and `old` refitted without its fold.

    The folds are the training groups (weight > 0) that hold the class, in sorted order,
    dealt round-robin into CROSSFIT_FOLDS folds; a fold's refits start from `new`'s and
    `old`'s parameters and train on every other training row. `refs` caches the refits of
    `old` by the groups a fold leaves out (one incumbent, many candidates; two classes make
    different folds). Every group's gain is out of sample, so under no effect its
    expectation is not above 0, as on the held-out groups."""
    gains = [old.row_nll(sub) - new.row_nll(sub)]
    groups = [sub.group]
    train = weights > 0
    of_class = d.class_index.numpy() == class_index
    holding = np.unique(d.group[train & of_class])
    for k in range(min(CROSSFIT_FOLDS, len(holding))):
        fold = holding[k::CROSSFIT_FOLDS]
        out = np.isin(d.group, fold)
        w = np.where(out, 0.0, weights)
        key = fold.tobytes()
        if key not in refs:
            refs[key] = fit(old.model, d, w, old.theta)
        refit = fit(new.model, d, w, new.theta)
        rows = d.rows_subset(np.flatnonzero(out & of_class))
        gains.append(refs[key].row_nll(rows) - refit.row_nll(rows))
        groups.append(rows.group)
    return by_groups(np.concatenate(gains), np.concatenate(groups))


def worth_crossfit(c: Comparison, support: Comparison | None, effect: Effect) -> bool:
    if support is None or effect.class_index < 0 or support.groups >= CROSSFIT_BELOW_GROUPS:
        return False
    if c.delta <= 0.0 or support.delta <= 0.0:
        return False
    t_bar = float(stats.t.isf(stats.norm.sf(Z_RESAMPLE), df=support.groups - 1))
    return support.delta > t_bar * support.se


def domain_rows(held_out: Design, effect: Effect, f: Fit) -> Design | None:
    """The held-out rows an effect confined by its own fit acts on (`Effect.domain`: the
    sector, the rings its training fit chose), if enough groups hold them.

    Like a class, such a domain is a few of the held-out tiles: all of its gain lies
    there, and scored over every tile its cluster z is diluted by the tiles it never
    touches."""
    if effect.domain is None or effect.label not in [e.label for e in f.model.effects]:
        return None
    k = [e.label for e in f.model.effects].index(effect.label)
    rows = np.flatnonzero(effect.domain(f.theta[f.model.slices()[k]], held_out))
    if len(np.unique(held_out.group[rows])) < MIN_SUPPORT_GROUPS:
        return None
    return held_out.subset(rows)


def class_rows(held_out: Design, effect: Effect) -> Design | None:
    """The held-out rows of a class-confined effect's class, if enough groups hold it."""
    if effect.class_index < 0:
        return None
    rows = np.flatnonzero(held_out.class_index.numpy() == effect.class_index)
    if len(np.unique(held_out.group[rows])) < MIN_SUPPORT_GROUPS:
        return None
    return held_out.subset(rows)
