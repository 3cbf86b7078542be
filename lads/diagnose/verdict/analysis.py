"""One diagnosis of a design: selection, stability, ambiguity, uncertainty and held-out
metrics (docs/diagnose.md §5.4-5.7). Pure computation on a `Design`; no files.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.base import Effect
from lads.diagnose.effects.catalogue import candidates
from lads.diagnose.fit.bootstrap import bootstrap_params
from lads.diagnose.fit.design import Design, evenly_spaced
from lads.diagnose.fit.likelihood import BASE_NAMES
from lads.diagnose.fit.model import Fit, fit_best, initial_base
from lads.diagnose.fit.parallel import one_thread
from lads.diagnose.selection.compare import Comparison, compare
from lads.diagnose.selection.grouping import Split, fit_weights, split_groups
from lads.diagnose.selection.select import (
    CLAIM_FREQUENCY,
    POSSIBLE_FREQUENCY,
    Z_ACCEPT,
    Selection,
    forward_backward,
)
from lads.diagnose.verdict.ambiguity import (
    ground_only_rule,
    range_band_rule,
    resample_swaps,
    separating_data,
    swap_ambiguity,
)
from lads.diagnose.verdict.heldout import heldout_metrics, noise_model
from lads.diagnose.verdict.intervals import ci95, sample_arrays
from lads.diagnose.verdict.settings import Settings
from lads.diagnose.verdict.stability import Stability, effect_family, stability

Z_TEST = CONFIG.verdict.z_test


@dataclass
class EffectReport:
    """A selected effect with its parameters, CIs and selection frequency."""

    effect: Effect
    params: dict[str, Any]
    ci95: dict[str, Any]
    selection_frequency: float
    status: str  # "claimed" | "possible"
    samples: dict[str, npt.NDArray[np.float64]] = field(default_factory=dict)
    unidentified: list[str] = field(default_factory=list)  # parameters the data do not inform


@dataclass
class Diagnosis:
    """Everything the report needs."""

    split: Split
    selection: Selection
    final: Fit
    effects: list[EffectReport]
    possible: list[dict[str, Any]]
    alternatives: list[dict[str, Any]]
    ambiguity_sets: list[dict[str, Any]]
    noise_model: dict[str, Any]
    heldout: dict[str, Any]
    verdict: str
    reasons: list[str]
    frequencies: dict[str, float]


# The verdict's reason when the simulation is the recording itself (`_reproduces`).
REPRODUCES = (
    "the simulation matches the recording within its resolution: every beam returns in "
    "both and every stored intensity is within one encoding step of the simulated one; what "
    "differs is rounding, not missing physics"
)
# The steps `diagnose_design` announces to its `phase` callback, in order.
PHASES = ("selection", "resamples", "final fit and bootstrap", "ambiguity, noise, held-out")


def diagnose_design(
    d: Design,
    rng: np.random.Generator,
    settings: Settings,
    phase: Callable[[str], None] | None = None,
) -> Diagnosis:
    """Select, stabilise, quantify and evaluate the effects that explain `d` (on one
    thread: `parallel.one_thread`). `phase` is called with each name of `PHASES` as that
    step starts (a progress display); it does not change the result."""
    with one_thread():
        return _diagnose_design(d, rng, settings, phase or (lambda name: None))


def _diagnose_design(
    d: Design, rng: np.random.Generator, settings: Settings, phase: Callable[[str], None]
) -> Diagnosis:
    phase(PHASES[0])
    split = split_groups(d, rng)
    weights = fit_weights(len(d), split.train, settings.fit_rows, rng)
    pool = candidates(d, train_rows=split.train)
    selecting = split.validation[evenly_spaced(len(split.validation), settings.selection_rows)]
    selection = forward_backward(
        d, pool, weights, selecting, k_max=settings.k_max, jobs=settings.jobs
    )
    phase(PHASES[1])
    stable = stability(d, pool, selection, split, settings, rng)

    # Final model on train + validation, bootstrap CIs on the same rows.
    phase(PHASES[2])
    fit_all = np.concatenate([split.train, split.validation])
    w_all = fit_weights(len(d), fit_all, settings.fit_rows * 2, rng)
    base = initial_base(d, fit_all)
    final = fit_best(selection.fit.model, d, w_all, base, selection.fit)
    boot = bootstrap_params(
        final, d, fit_all, settings.fit_rows, settings.bootstrap, rng, settings.jobs
    )
    effects = _effect_reports(final, d, w_all, boot, stable.family_frequency)
    possible = _possible(pool, final, stable)

    phase(PHASES[3])
    reasons: list[str] = []
    alternatives, sets = _ambiguity(
        d, selection, pool, weights, split, settings, stable, effects, reasons
    )
    noise = noise_model(final, d, boot, selection, weights, split)
    heldout = heldout_metrics(d, split.test, selection.baseline, final)
    beyond = _beyond_bounds(selection)
    reasons += _bound_reasons(beyond)
    test_gain = compare(final, selection.baseline, d, split.test, 1.0, 1.0)
    heldout["test_gain_nats"] = {"delta": test_gain.delta, "se": test_gain.se}
    verdict = _verdict(effects, possible, sets, test_gain, bool(beyond), reasons)
    if _reproduces(d):
        # Below one step the residuals are rounding (a spike and a few single steps): the
        # Gaussian noise model misfits them, and tiny shifts toward each stored interval's
        # ln-space centre "gain". Nothing the recording can resolve is missing.
        effects, possible, alternatives, sets = [], [], [], []
        verdict, reasons = "no_missing_physics", [REPRODUCES]
    return Diagnosis(
        split,
        selection,
        final,
        effects,
        possible,
        alternatives,
        sets,
        noise,
        heldout,
        verdict,
        reasons,
        stable.frequency,
    )


def _reproduces(d: Design) -> bool:
    """Whether a paired simulation matches the recording within its resolution: reality
    returned every beam, and every stored real intensity is within one encoding step of the
    simulated one (y = ln(i + h) on both sides, h the half step)."""
    if not d.paired or not bool(d.returned.all()):
        return False
    gap = (torch.exp(d.y) - torch.exp(d.ln_sim)).abs()
    return bool((gap <= d.step * (1.0 + 1e-6)).all())


def _ambiguity(
    d: Design,
    selection: Selection,
    pool: list[Effect],
    weights: npt.NDArray[np.float64],
    split: Split,
    settings: Settings,
    stable: Stability,
    effects: list[EffectReport],
    reasons: list[str],
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(alternatives, ambiguity sets): the swaps within one SE, then the sets of the range
    band, the stability resamples and the ground-only rule. The rules' reasons, and those
    of claims the sets demote (`claim_with_sets`), are appended to `reasons`."""
    alternatives, sets = swap_ambiguity(d, selection, pool, weights, split, settings.jobs)
    sets += range_band_rule(d, selection, reasons)
    sets += resample_swaps(selection.labels, stable.chosen_sets, pool, stable.family, sets)
    sets += ground_only_rule(d, selection, reasons)
    if settings.resamples > 0:
        ids_by_label = {e.label: e.info.id for e in pool}
        chosen_ids = [{ids_by_label[label] for label in labels} for labels in stable.chosen_sets]
        reasons += claim_with_sets(effects, sets, chosen_ids)
    return alternatives, sets


def _bound_reasons(beyond: list[tuple[str, float]]) -> list[str]:
    """A reason for each (label, z) of `_beyond_bounds`."""
    return [
        f"{label} would improve the held-out fit by {z:.1f} SE but a parameter sits at "
        "its catalogue bound: the mismatch it describes is larger than the catalogue "
        "allows for it, or another effect is missing"
        for label, z in beyond
    ]


def _effect_reports(
    final: Fit,
    d: Design,
    w_all: npt.NDArray[np.float64],
    boot: npt.NDArray[np.float64],
    fam_freq: dict[str, float],
) -> list[EffectReport]:
    """One report per effect of the final model: parameters, bootstrap intervals (the
    catalogue range for a parameter no fitted row informs) and claimed / possible status.
    `boot` is (B, P): the final model's parameters refitted on B bootstrap resamples."""
    effects = []
    flat = final.flat_parameters(d, w_all)
    for e, sl in zip(final.model.effects, final.model.slices(), strict=True):
        theta = final.theta[sl]
        params = e.export(theta)
        samples = np.array([e.export(b[sl]) for b in boot], dtype=object)
        ci = ci95(params, list(samples), e.extra.get("ci_floor", {}))
        unidentified = [n for n in flat.get(e.label, []) if n in params]
        for n in unidentified:
            # Anywhere in the catalogue range fits as well: that range is the interval.
            j = e.names.index(n)
            ci[n] = [float(e.lower[j]), float(e.upper[j])]
        f = fam_freq.get(e.label, 0.0)
        status = "claimed" if f >= CLAIM_FREQUENCY else "possible"
        effects.append(
            EffectReport(e, params, ci, f, status, sample_arrays(params, samples), unidentified)
        )
    return effects


def _possible(pool: list[Effect], final: Fit, stable: Stability) -> list[dict[str, Any]]:
    """Families outside the final model that the resamples chose often enough to mention."""
    possible = []
    listed = {effect_family(e) for e in final.model.effects}
    for e in sorted(pool, key=lambda e: -stable.frequency.get(e.label, 0.0)):
        f = stable.family_frequency.get(e.label, 0.0)
        if stable.family[e.label] not in listed and f >= POSSIBLE_FREQUENCY:
            listed.add(stable.family[e.label])
            possible.append(
                {"id": e.info.id, "key": e.info.key, "label": e.label, "selection_frequency": f}
            )
    return possible


def _verdict(
    effects: list[EffectReport],
    possible: list[dict[str, Any]],
    sets: list[dict[str, Any]],
    test_gain: Comparison,
    beyond: bool,
    reasons: list[str],
) -> str:
    """The diagnosis' verdict (docs/diagnose.md §2); appends its reasons to `reasons`."""
    claimed = [r for r in effects if r.status == "claimed"]
    ambiguous_ids = {i for s in sets for i in s["ids"]}
    if not claimed and effects and test_gain.delta > Z_TEST * test_gain.se:
        # Something real is missing (the test groups say so) but no single effect is
        # selected stably enough to name: the data cannot decide which.
        reasons.append(
            f"the selected effects improve the test groups by {test_gain.delta:.4f} nats/row "
            f"({test_gain.delta / max(test_gain.se, 1e-12):.1f} SE) but were chosen in fewer "
            "than 70 % of the resamples"
        )
        return "ambiguous"
    if not claimed and beyond:
        # Held-out data say something is missing, the catalogue cannot fit it in range.
        return "ambiguous"
    if not claimed:
        if possible:
            reasons.append("effects were selected in fewer than 70 % of the resamples")
        return "no_missing_physics"
    if all(r.effect.info.id in ambiguous_ids for r in claimed):
        return "ambiguous"
    return "effects_found"


def claim_with_sets(
    effects: list[EffectReport], sets: list[dict[str, Any]], chosen_ids: list[set[str]]
) -> list[str]:
    """Claim (in place) each unclaimed effect whose ambiguity set is chosen, by one member
    or another, in >= CLAIM_FREQUENCY of the resamples (`chosen_ids`: the IDs each chose);
    returns the reasons to report.

    Members of an ambiguity set fit within 1 SE of each other (§5.5 step 8): when the set
    is stable the mismatch is, and only its form is open, which the set says; counted
    apart, a range law the resamples split between two forms would read as no range term."""
    reasons = []
    n = max(len(chosen_ids), 1)
    for r in effects:
        if r.status == "claimed":
            continue
        for group in (set(x["ids"]) for x in sets if r.effect.info.id in x["ids"]):
            hit = sum(1 for ids in chosen_ids if ids & group) / n
            if hit >= CLAIM_FREQUENCY:
                r.status = "claimed"
                reasons.append(
                    f"{r.effect.label} is claimed with its ambiguity set "
                    f"{sorted(group)}: one of them, in any of its forms (a class or "
                    f"law variant counts as its ID), was chosen in {hit:.0%} of the "
                    "resamples"
                )
                break
    return reasons


def _beyond_bounds(sel: Selection) -> list[tuple[str, float]]:
    """(label, z) of unselected candidates rejected only for a parameter at a bound."""
    chosen = set(sel.labels)
    best: dict[str, float] = {}
    for s in sel.trace:
        if s.at_bound and s.candidate not in chosen:
            if s.z > Z_ACCEPT and s.delta_loss > sel.floor:
                best[s.candidate] = max(s.z, best.get(s.candidate, 0.0))
    return sorted(best.items(), key=lambda kv: -kv[1])


__all__ = ["BASE_NAMES", "Diagnosis", "EffectReport", "Settings", "diagnose_design",
           "heldout_metrics", "separating_data"]  # fmt: skip
