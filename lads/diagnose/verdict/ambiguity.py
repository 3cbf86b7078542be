"""Where a diagnosis cannot tell effects apart: effects that swap for one another within a
standard error on held-out groups, in the stability resamples, or by a rule of the data
(ground-only scans, too few long-range returns), with the data that would separate them."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.base import Effect
from lads.diagnose.effects.catalogue import CATALOGUE
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.likelihood import Model
from lads.diagnose.fit.model import initial_base
from lads.diagnose.fit.parallel import fit_models
from lads.diagnose.selection.compare import Comparison, gain_on
from lads.diagnose.selection.grouping import Split
from lads.diagnose.selection.select import CLAIM_FREQUENCY, POSSIBLE_FREQUENCY, Selection

LONG_RANGE_BAND_M = CONFIG.verdict.long_range_band_m
LONG_RANGE_MIN_SHARE = CONFIG.verdict.long_range_min_share
# On flat ground cos theta = h / R, so ln I_sim = ln(c rho h) - 3 ln R: a range exponent, an
# incidence law, per-ring gains (each ring meets the ground at one range) and the encoding's
# gamma (a multiple of ln I_sim) are all functions of range there, apart from the few
# ground classes' reflectances, so on ground-only data any one of them can absorb the others.
GROUND_IDENTITIES = ("C1", "C3", "C4", "C9")
GROUND_ONLY_SHARE = CONFIG.verdict.ground_only_share


def swap_ambiguity(
    d: Design,
    sel: Selection,
    pool: list[Effect],
    weights: npt.NDArray[np.float64],
    split: Split,
    jobs: int = 1,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Unselected candidates that, swapped in for a selected effect, fit within 1 SE.

    An alternative that fits *better* by more than 1 SE is not an ambiguity but a sign the
    greedy order went wrong; the backward pass and the stability resamples catch those.
    `delta_loss` is the alternative's held-out loss minus the chosen model's (nats/row)."""
    alternatives: list[dict[str, Any]] = []
    sets: list[dict[str, Any]] = []
    chosen = sel.fit
    if not chosen.model.effects:
        return alternatives, sets
    base = initial_base(d, np.flatnonzero(weights > 0))
    held_out = d.subset(split.validation)
    swaps = _swaps(sel, pool)
    # A swapped model the selection already fitted on these rows is not fitted again.
    todo = [m for _, _, m in swaps if m.key not in sel.fitted]
    fits = dict(
        zip((m.key for m in todo), fit_models(todo, d, weights, base, chosen, jobs), strict=True)
    )
    for e in chosen.model.effects:
        members = [e.info.id]
        for _, cand, m in (s for s in swaps if s[0] is e):
            swapped = sel.fitted.get(m.key) or fits[m.key]
            # c.delta = held-out loss of the swapped model minus the chosen one (nats/row):
            # positive when the chosen effect fits better.
            c = gain_on(chosen, swapped, held_out)
            if abs(c.delta) <= c.se:
                members.append(cand.info.id)
                alternatives.append(_alternative(e, cand, c))
        if len(members) > 1:
            sets.append(
                {
                    "ids": members,
                    "keys": [CATALOGUE[i].key for i in members],
                    "reason": f"swapping {e.label} for any other member changes the held-out loss "
                    "by less than one standard error",
                }
            )
    return alternatives, sets


def _swaps(sel: Selection, pool: list[Effect]) -> list[tuple[Effect, Effect, Model]]:
    """(selected effect, candidate, the chosen model with the candidate in its place) for
    every unselected candidate that confounds with a selected effect or was among the four
    best first steps."""
    chosen = sel.fit
    selected = set(sel.labels)
    ranked = sorted(sel.first_step.items(), key=lambda kv: -kv[1].delta)
    top = {label for label, _ in ranked[:4]}
    swaps = []
    for e in chosen.model.effects:
        for cand in pool:
            # Another parametrisation of the same catalogue effect is not an alternative.
            if cand.label in selected or cand.info.id == e.info.id:
                continue
            if cand.info.id in e.info.confounds or cand.label in top:
                swaps.append((e, cand, chosen.model.without(e.label).with_effect(cand)))
    return swaps


def _alternative(e: Effect, cand: Effect, c: Comparison) -> dict[str, Any]:
    """The report entry of `cand` fitting within one SE (`c`) of the selected effect `e`."""
    return {
        "id": cand.info.id,
        "key": cand.info.key,
        "label": cand.label,
        "ids": [cand.info.id],
        "keys": [cand.info.key],
        "instead_of": [e.info.id],
        "delta_loss": c.delta,
        "se": c.se,
        "separating_data": separating_data(e.info.id, cand.info.id),
    }


def resample_swaps(
    selected: list[str],
    chosen_sets: list[list[str]],
    pool: list[Effect],
    family: dict[str, tuple[str, str | None]],
    known: list[dict[str, Any]],
) -> list[dict[str, Any]]:
    """Ambiguity sets the stability resamples show: an unselected candidate chosen *instead
    of* a selected effect (the one absent, the other present) in >= POSSIBLE_FREQUENCY of
    the resamples, the two together in >= CLAIM_FREQUENCY. `chosen_sets`: the labels each
    resample chose; `known`: sets already listed (not repeated).

    The held-out swap test (`_ambiguity`) compares the two fits on one split; the resamples
    redraw the training tiles: two forms the main split ranks a little apart, each chosen
    in about half the resamples, are one mismatch the data cannot tell apart, not two
    "possible" ones."""
    n = len(chosen_sets)
    if n == 0:
        return []
    by_label = {e.label: e for e in pool}
    listed = [set(x["ids"]) for x in known]
    out: list[dict[str, Any]] = []
    for s in selected:
        for e in pool:
            u = e.label
            if u in selected or family[u] == family[s]:
                continue
            instead = sum(1 for c in chosen_sets if u in c and s not in c) / n
            either = sum(1 for c in chosen_sets if u in c or s in c) / n
            if instead < POSSIBLE_FREQUENCY or either < CLAIM_FREQUENCY:
                continue
            ids = [by_label[s].info.id, e.info.id]
            if ids[0] == ids[1] or any(set(ids) <= x for x in listed):
                continue
            listed.append(set(ids))
            out.append(
                {
                    "ids": ids,
                    "keys": [CATALOGUE[i].key for i in ids],
                    "reason": f"the resamples chose {u} instead of {s} in {instead:.0%} of "
                    f"them and one of these two forms in {either:.0%}",
                }
            )
    return out


def separating_data(a: str, b: str) -> str:
    """The data that would tell two confounded effects apart (docs/diagnose.md §2, §5.4)."""
    pair = {a, b}
    if pair == {"C1", "C5"}:
        return (
            "returns beyond 60 m: attenuation curves ln I by -2 alpha R, the exponent by "
            "-delta_n / R (d ln I / dR = -delta_n / R - 2 alpha)"
        )
    if pair == {"C1", "C3"}:
        return (
            "non-ground surfaces (walls, vehicles, poles) where incidence and range vary "
            "independently; on flat ground cos(theta) = h / R"
        )
    if pair & {"C4", "D3"} and pair & {"C1", "C2"}:
        return (
            "non-ground returns on every ring: on the ground each ring meets one range, "
            "R_k = h / sin|elevation_k|"
        )
    if pair == {"C1", "C2"}:
        return "many returns below 10 m and an exponent fitted beyond 15 m"
    if "C6" in pair:
        return "the same class seen over a wide span of incidence angles and ranges"
    if pair == {"D1", "D2"}:
        return "dropped beams at normal incidence but long range, or grazing but near"
    return "more scans, spread over range, incidence, ring and class"


def ground_only_rule(d: Design, sel: Selection, reasons: list[str]) -> list[dict[str, Any]]:
    """§2 item 3, §5.4: on ground alone a range exponent, an incidence law, per-ring gains
    and the encoding's gamma are one function of range (GROUND_IDENTITIES), so a selected
    one of them is reported with the others when < GROUND_ONLY_SHARE of the intensity rows
    lie off the ground."""
    if not {e.info.id for e in sel.fit.model.effects} & set(GROUND_IDENTITIES):
        return []
    rows = d.fits_intensity
    off_ground = float(np.mean(~d.is_ground.numpy()[rows])) if rows.any() else 0.0
    if off_ground >= GROUND_ONLY_SHARE:
        return []
    reasons.append(
        f"only {off_ground:.1%} of the returns lie off the ground: a range exponent, "
        "an incidence law, per-ring gains and an encoding gamma cannot be told "
        "apart there"
    )
    keys = [CATALOGUE[i].key for i in GROUND_IDENTITIES]
    reason = ("ground-only data: not separable from ground data (add walls, vehicles or poles, "
              "where incidence, range and ring vary independently)")  # fmt: skip
    return [{"ids": list(GROUND_IDENTITIES), "keys": keys, "reason": reason}]


def range_band_rule(d: Design, sel: Selection, reasons: list[str]) -> list[dict[str, Any]]:
    """§5.4: name C5 over C1 only when >= 5 % of rows lie at 30-120 m."""
    if "C5" not in sel.labels:
        return []
    r = d.range_m.numpy()
    share = float(np.mean((r >= LONG_RANGE_BAND_M[0]) & (r <= LONG_RANGE_BAND_M[1])))
    if share >= LONG_RANGE_MIN_SHARE:
        return []
    reasons.append(
        f"only {share:.1%} of returns lie at 30-120 m: attenuation and a range "
        "exponent cannot be told apart"
    )
    return [
        {
            "ids": ["C5", "C1"],
            "keys": ["atmospheric_attenuation", "range_exponent"],
            "reason": "too few returns at 30-120 m (add returns beyond 60 m)",
        }
    ]
