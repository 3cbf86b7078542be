"""Choosing the effects: grouped splits, forward selection, backward pass, stability,
ambiguity and bootstrap uncertainty (docs/diagnose.md §5.4-5.5).

Every split and resample is over spatial groups (scan x 10 m tile), never points: the
effective sample size of LiDAR residuals is the number of independent surfaces (§2 item 4).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import stats

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.base import Effect
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.likelihood import Model
from lads.diagnose.fit.model import Fit, fit, initial_base
from lads.diagnose.fit.parallel import fit_models, fit_warm
from lads.diagnose.selection.compare import (
    Comparison,
    Incumbent,
    compare_groups,
    compare_on,
    design_effect_scale,
    gain_on,
)
from lads.diagnose.selection.support import (
    class_rows,
    crossfit_support,
    domain_rows,
    worth_crossfit,
)
from lads.errors import DiagnoseError

K_MAX = CONFIG.select.k_max
MIN_GAIN_NATS = CONFIG.select.min_gain_nats
BASELINE_SHARE = CONFIG.select.baseline_share
# Held-out directional score (model.directional_gain) needed to accept, in cluster standard
# errors: two-sided 5 % with a Bonferroni correction over the ~20 candidates of a forward
# step, so data without an effect rarely admit a chance winner. The score, not the held-out
# NLL gain, is the test: the gain's z is about half the score's for the same effect (it also
# pays for the new fit's own noise), so a bar of 3 on the gain would be a bar of ~6 on the
# evidence and miss real effects. The gain still decides among passing candidates and must
# beat `gain_floor`.
Z_ACCEPT = CONFIG.select.z_accept
# The stability resamples re-run the choice at a lower bar: the main selection has already
# tested significance; a resample asks whether the *same* effect wins when the training
# groups change, and the 70 % frequency rule is the error control there (stability
# selection). Re-testing at z >= 3 would drop a real effect near the bar from most resamples.
Z_RESAMPLE = CONFIG.select.z_resample
# dBIC is reported in the trace, not used to accept. docs/diagnose.md §5.5 asks for dBIC < -10
# with n_eff from the Kish design effect; but the design effect measures correlation
# *between* groups (object reflectance), while per-ring and per-class terms vary *within* a
# surface, so that rule rejected 64 ring gains that improved held-out fit by four standard
# errors. The grouped held-out test with a cluster SE is the guard that is right for both.
# Screening: a forward step fits every candidate on SCREEN_ROWS training rows (a quarter of
# Settings.fit_rows), then refits the SHORTLIST best (and the SHORTLIST_CONFINED best
# class-confined ones) on all of them. Fit time is linear in rows, so a step over ~25
# candidates costs ~1/3 of full fits, and the decision still rests on full fits.
SCREEN_ROWS = CONFIG.select.screen_rows
SHORTLIST = CONFIG.select.shortlist
SHORTLIST_CONFINED = CONFIG.select.shortlist_confined
CLAIM_FREQUENCY = CONFIG.select.claim_frequency
POSSIBLE_FREQUENCY = CONFIG.select.possible_frequency


@dataclass
class Step:
    """One candidate evaluated at one forward step (the selection trace)."""

    step: int
    candidate: str
    delta_loss: float
    se: float
    delta_bic: float
    at_bound: bool
    accepted: bool = False
    support: Comparison | None = None
    screened: bool = False  # fitted on the screening rows only (not shortlisted)
    z: float = 0.0  # the held-out directional score in cluster SEs (the acceptance test)
    crossfit: bool = False  # support pooled with cross-fitted training groups

    @classmethod
    def of(cls, step: int, label: str, c: Comparison, at_bound: bool, **kw: Any) -> Step:
        return cls(step, label, c.delta, c.se, c.delta_bic, at_bound, z=c.z, **kw)

    def to_json(self) -> dict[str, Any]:
        out = {
            "step": self.step,
            "candidate": self.candidate,
            "delta_loss": self.delta_loss,
            "se": self.se,
            "z": self.z,
            "delta_bic": self.delta_bic,
            "at_bound": self.at_bound,
            "accepted": self.accepted,
            "screened": self.screened,
        }
        if self.support is not None:
            out["class_rows"] = {
                "delta_loss": self.support.delta,
                "se": self.support.se,
                "t": self.support.delta / max(self.support.se, 1e-300),
                "groups": self.support.groups,
                "statistic": "mean of group mean gains"
                + (", held-out and cross-fitted training groups" if self.crossfit else ""),
            }
        return out


@dataclass
class Selection:
    """Result of forward + backward selection on one training sample."""

    fit: Fit
    baseline: Fit
    trace: list[Step] = field(default_factory=list)
    first_step: dict[str, Comparison] = field(default_factory=dict)
    # Every model fitted on all the training rows, and those fitted on the screening rows
    # only, by set of effects: the starts of the stability resamples (`parallel.fit_warm`).
    fitted: dict[frozenset[str], Fit] = field(default_factory=dict)
    screened_fits: dict[frozenset[str], Fit] = field(default_factory=dict)
    floor: float = MIN_GAIN_NATS  # the held-out gain an effect had to beat (`gain_floor`)

    def starts(self) -> dict[frozenset[str], Fit]:
        return {**self.screened_fits, **self.fitted}

    @property
    def labels(self) -> list[str]:
        return [e.label for e in self.fit.model.effects]


def _passes(
    c: Comparison,
    at_bound: bool,
    z_accept: float,
    floor: float,
    support: Comparison | None = None,
) -> bool:
    """The directional score beats `z_accept` and the NLL gain beats `floor` (nats/row) on
    all held-out rows; or, for a class-confined effect, the gain over its class's groups
    beats the t bar and the floor. Either way a confined effect (`support` given) must gain
    on its own rows.

    On class rows the gain, not the score, is tested: a group mean of per-row scores over
    a few tiles is heavy-tailed, and with the score a chance offset of the few cars in a
    sample (their own reflectance draws) passed the t bar."""
    if at_bound:
        return False
    if support is not None and support.delta <= 0.0:
        # A confined effect changes its own rows only: a gain over all rows with a loss on
        # those is the refitted baseline's (gain, noise, return rate), not the effect's: a
        # small sector effect can pass the z bar over all rows while losing on its own tiles.
        return False
    if c.z > z_accept and c.delta > floor:
        return True
    if support is None or c.delta <= 0.0:
        return False
    t_crit = float(stats.t.isf(stats.norm.sf(z_accept), df=support.groups - 1))
    return support.delta > t_crit * support.se and support.delta > floor


def gain_floor(baseline_half_deviance: float) -> float:
    """The smallest held-out NLL gain (nats/row) an effect is accepted for: MIN_GAIN_NATS,
    or BASELINE_SHARE of the baseline's held-out loss if larger (docs/diagnose.md §5.5 step 4),
    the loss being the deviance (`RowTerms.half_deviance`, nats/row).

    The directional score finds consistent effects far below the noise; the floor keeps
    the ones too small to matter out, such as a class whose few objects happen to be
    brighter than its mean in this sample. A share of the NLL itself made the floor depend
    on the noise level through the Gaussian normaliser, and counted each quantisation
    interval's probability as misfit, which is larger on coarse encodings and kept real,
    small effects out."""
    return max(MIN_GAIN_NATS, BASELINE_SHARE * baseline_half_deviance)


def screening_weights(
    weights: npt.NDArray[np.float64], rows: int | None
) -> npt.NDArray[np.float64] | None:
    """`weights` thinned to about `rows` of its rows (every k-th, in order), or None."""
    use = np.flatnonzero(weights > 0)
    if rows is None or len(use) <= rows:
        return None
    out = np.zeros_like(weights)
    keep = use[:: -(-len(use) // rows)]
    out[keep] = weights[keep]
    return out


def _shortlist(screened: list[tuple[Effect, Fit, Comparison, Comparison | None]]) -> set[str]:
    """Labels worth a full fit: the SHORTLIST best held-out gains of the screening fits,
    and the SHORTLIST_CONFINED best class-row t ratios of class-confined candidates (whose
    gain over all rows is small by construction, see MIN_SUPPORT_GROUPS)."""
    by_gain = sorted(screened, key=lambda r: -r[2].delta)[:SHORTLIST]
    confined = [r for r in screened if r[3] is not None and r[2].delta > 0.0]
    by_t = sorted(confined, key=lambda r: -r[3].delta / max(r[3].se, 1e-12))  # type: ignore[union-attr]
    return {r[0].label for r in by_gain} | {r[0].label for r in by_t[:SHORTLIST_CONFINED]}


def _simplest_within_one_se(
    ok: list[tuple[Effect, Fit, Comparison, bool, Comparison | None]],
    held_out: Design,
) -> tuple[Effect, Fit, Comparison, bool, Comparison | None]:
    """The passing candidate to accept: the fewest parameters among those whose held-out loss
    is within one paired SE of the best gain's (the one-standard-error rule).

    A flexible effect can out-gain the true one by less than its own noise: 64 ring offsets
    fitted the ground's incidence falloff (each ring meets the ground at one range and
    angle) 0.005 nats better than the one-parameter incidence law, at a third of its z."""
    top = max(ok, key=lambda r: r[2].delta)
    tied = [top]
    for r in ok:
        if r is top:
            continue
        c = gain_on(top[1], r[1], held_out)
        if c.delta <= c.se:
            tied.append(r)
    return min(tied, key=lambda r: (r[0].size, -r[2].delta))


def forward_backward(
    d: Design,
    pool: list[Effect],
    weights: npt.NDArray[np.float64],
    validation: npt.NDArray[np.int64],
    *,
    heteroscedastic: bool = True,
    k_max: int = K_MAX,
    refs: tuple[float, float] | None = None,
    z_accept: float = Z_ACCEPT,
    screen_rows: int | None = SCREEN_ROWS,
    jobs: int = 1,
    warm: dict[frozenset[str], Fit] | None = None,
    floor: float | None = None,
) -> Selection:
    """Greedy forward selection on held-out loss, then a backward pass (§5.5 steps 3-6).

    With `screen_rows`, each forward step first fits every candidate on that many of the
    training rows and refits only a shortlist (`_shortlist`) on all of them; the
    acceptance tests read the full fits only. The candidates of a step are fitted on `jobs`
    processes (results do not depend on it).

    `refs` (mean ln R, mean ln I_sim) centre the noise model; default: those of `d` (pass
    the whole design's when `d` is a part of it). `warm`: fits to start from, by effect set
    (a resample passes the main selection's `fitted`); a model not in it is fitted from
    every start. `floor`: the held-out gain to beat (nats/row); default `gain_floor`."""
    fit_rows = np.flatnonzero(weights > 0)
    base = initial_base(d, fit_rows)
    scale = design_effect_scale(d, fit_rows)
    n_fit = float(weights.sum())
    refs = refs if refs is not None else reference_levels(d)
    model = Model([], refs[0], refs[1], heteroscedastic)
    baseline = fit_warm(model, d, weights, base, None, warm)
    current = baseline
    held_out = d.subset(validation)
    incumbent = Incumbent.of(current, held_out)
    if floor is None:
        floor = gain_floor(float(np.mean(incumbent.terms.half_deviance(held_out))))
    sel = Selection(current, baseline, floor=floor)
    sel.fitted[model.key] = baseline
    remaining = list(pool)
    supports = {e.label: class_rows(held_out, e) for e in pool}
    screen_w = screening_weights(weights, screen_rows)

    def assess(cand: Effect, f: Fit, n_w: float, ref: Fit, incumbent: Incumbent) -> tuple:
        c = compare_on(f, ref, held_out, scale, n_w, incumbent)
        sub = supports[cand.label]
        if sub is None:
            sub = domain_rows(held_out, cand, f)
        return c, None if sub is None else compare_groups(f, ref, sub)

    for step in range(1, k_max + 1):
        results = []
        listed = list(remaining)
        if screen_w is not None and len(remaining) > SHORTLIST:
            listed = _screen(
                step, remaining, current, d, screen_w, base, held_out, sel, assess, jobs, warm
            )
        fits = fit_models(
            [current.model.with_effect(c) for c in listed], d, weights, base, current, jobs, warm
        )
        fold_refs: dict[bytes, Fit] = {}
        for cand, f in zip(listed, fits, strict=True):
            sel.fitted[f.model.key] = f
            c, support = assess(cand, f, n_fit, current, incumbent)
            bound = cand.label in f.binding_bounds(d, weights)
            crossfit = not _passes(c, bound, z_accept, floor, support) and worth_crossfit(
                c, support, cand
            )
            if crossfit:
                class_sub = supports[cand.label]
                if class_sub is None:  # a class-confined support is its class's held-out rows
                    raise DiagnoseError(f"{cand.label}: cross-fit without held-out class rows.")
                support = crossfit_support(
                    f, current, d, weights, class_sub, cand.class_index, fold_refs
                )
            results.append((cand, f, c, bound, support))
            sel.trace.append(
                Step.of(step, cand.label, c, bound, support=support, crossfit=crossfit)
            )
            if step == 1:
                sel.first_step[cand.label] = c
        # The best held-out gain, or a simpler effect within one SE of it.
        ok = [r for r in results if _passes(r[2], r[3], z_accept, floor, r[4])]
        if not ok:
            break
        best = _simplest_within_one_se(ok, held_out)
        for s in sel.trace:
            if s.step == step:
                s.accepted = s.candidate == best[0].label
        current = best[1]
        incumbent = Incumbent.of(current, held_out)
        remaining = [c for c in remaining if c.label != best[0].label]
    sel.fit = _backward(current, d, weights, base, warm, held_out, scale, n_fit)
    return sel


def _screen(
    step: int,
    remaining: list[Effect],
    current: Fit,
    d: Design,
    screen_w: npt.NDArray[np.float64],
    base: npt.NDArray[np.float64],
    held_out: Design,
    sel: Selection,
    assess: Callable[[Effect, Fit, float, Fit, Incumbent], tuple[Any, ...]],
    jobs: int,
    warm: dict[frozenset[str], Fit] | None,
) -> list[Effect]:
    """The shortlist of one forward step: every candidate fitted on the screening rows and
    scored; the others are traced as screened out."""
    screened = []
    fits = fit_models(
        [current.model.with_effect(c) for c in remaining], d, screen_w, base, current, jobs, warm
    )
    # Against the incumbent refitted on the same screening rows: against the one fitted on
    # all rows, the base parameters' own sampling noise (the return rate) moved every
    # held-out group alike and could give every candidate the same gain, far beyond the z
    # bar, with no effect present.
    screen_ref = fit(current.model, d, screen_w, current.theta)
    screen_inc = Incumbent.of(screen_ref, held_out)
    for cand, f in zip(remaining, fits, strict=True):
        sel.screened_fits[f.model.key] = f
        screened.append((cand, f, *assess(cand, f, float(screen_w.sum()), screen_ref, screen_inc)))
    shortlist = _shortlist(screened)
    for cand, f, c, support in screened:
        if cand.label in shortlist:
            continue
        sel.trace.append(
            Step.of(
                step,
                cand.label,
                c,
                cand.label in f.binding_bounds(d, screen_w),
                support=support,
                screened=True,
            )
        )
        if step == 1:
            sel.first_step[cand.label] = c
    return [c for c in remaining if c.label in shortlist]


def _backward(
    current: Fit,
    d: Design,
    weights: npt.NDArray[np.float64],
    base: npt.NDArray[np.float64],
    warm: dict[frozenset[str], Fit] | None,
    held_out: Design,
    scale: float,
    n_fit: float,
) -> Fit:
    """Backward pass: drop any effect whose removal costs less than 1 SE (of the score)."""
    changed = True
    while changed and current.model.effects:
        changed = False
        for e in list(current.model.effects):
            reduced = fit_warm(current.model.without(e.label), d, weights, base, current, warm)
            c = compare_on(current, reduced, held_out, scale, n_fit)
            if c.z < 1.0:
                current = reduced
                changed = True
                break
    return current


def reference_levels(d: Design) -> tuple[float, float]:
    """(mean ln R, mean ln I_sim) of the design: the centre of the noise model."""
    return float(d.ln_range.mean()), float(d.ln_sim.mean())
