"""Stability of a selection: the selection rerun on group-bootstrap resamples of the training
groups, and how often each candidate (and each effect family) wins (docs/diagnose.md §2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.diagnose.effects.base import Effect
from lads.diagnose.fit.bootstrap import bootstrap_weights
from lads.diagnose.fit.design import Design, evenly_spaced
from lads.diagnose.fit.model import Fit
from lads.diagnose.fit.parallel import map_fits, one_thread
from lads.diagnose.selection.grouping import Split
from lads.diagnose.selection.select import (
    MIN_GAIN_NATS,
    Z_RESAMPLE,
    Selection,
    forward_backward,
    reference_levels,
)
from lads.diagnose.verdict.settings import Settings


@dataclass(frozen=True)
class Stability:
    """How often the resampled selections chose each candidate (by label) and its family."""

    chosen_sets: list[list[str]]
    frequency: dict[str, float]
    family_frequency: dict[str, float]
    family: dict[str, tuple[str, str | None]]


def stability(
    d: Design,
    pool: list[Effect],
    selection: Selection,
    split: Split,
    settings: Settings,
    rng: np.random.Generator,
) -> Stability:
    """Rerun the selection on group-bootstrap resamples of the training groups.

    Over the candidates that earned a full fit and passed the resamples' bar at some forward
    step (a score z > Z_RESAMPLE and a gain above the floor: the rest never win), and at most
    one step beyond the main selection: the resamples ask whether the same effects win, which
    costs a full selection each."""
    strong = {
        s.candidate
        for s in selection.trace
        if not s.screened and s.z > Z_RESAMPLE and s.delta_loss > selection.floor
    }
    contenders = [e for e in pool if e.label in strong or e.label in selection.labels]
    names = {e.label for e in contenders}
    k_resample = min(settings.k_max, len(selection.labels) + 1)
    counts = dict.fromkeys((e.label for e in pool), 0)
    ws = bootstrap_weights(d, split.train, settings.fit_rows, settings.resamples, rng)
    warm = {k: f for k, f in selection.starts().items() if all(lb in names for lb in k)}
    # Scoring, not fitting, is what grows with the scans: a full-scan diagnosis holds ~400k
    # validation rows against 15000 fitted ones, and each resample scores every contender on
    # them. Every k-th row keeps every group and surface; the resamples ask whether the
    # same effects win, which the main selection has already tested on all rows.
    scoring = split.validation[evenly_spaced(len(split.validation), settings.resample_rows)]
    chosen_sets = map_fits(
        _resample_labels,
        d,
        ws,
        scoring,
        settings.jobs,
        contenders,
        k_resample,
        reference_levels(d),
        warm,
    )
    # Parametrisations of one effect (C3 as cos^p or as Oren-Nayar roughness) are one answer
    # to "is this effect there": a resample that picks the other form still selects it. Counted
    # apart, an incidence law chosen in every resample, in some as Oren-Nayar and in the others
    # as cos^p, was reported as "possible" twice instead of claimed once.
    family = {e.label: effect_family(e) for e in pool}
    family_counts: dict[tuple[str, str | None], int] = {}
    for labels in chosen_sets:
        for label in labels:
            counts[label] += 1
        for fam in {family[label] for label in labels}:
            family_counts[fam] = family_counts.get(fam, 0) + 1
    n_res = max(settings.resamples, 1)
    freq = {k: v / n_res for k, v in counts.items()}
    fam_freq = {k: family_counts.get(family[k], 0) / n_res for k in counts}
    if settings.resamples == 0:
        chosen = {family[k] for k in selection.labels}
        freq = {k: 1.0 if k in selection.labels else 0.0 for k in counts}
        fam_freq = {k: 1.0 if family[k] in chosen else 0.0 for k in counts}
    return Stability(chosen_sets, freq, fam_freq, family)


def effect_family(e: Effect) -> tuple[str, str | None]:
    """(catalogue ID, class) of an effect: its parametrisations share it, classes do not."""
    return e.info.id, e.class_name


def _resample_labels(
    d: Design,
    ws: list[npt.NDArray[np.float64]],
    validation: npt.NDArray[np.int64],
    contenders: list[Effect],
    k_max: int,
    refs: tuple[float, float],
    warm: dict[frozenset[str], Fit],
) -> list[list[str]]:
    """The labels selected on each resample (a `map_fits` task), each fit started from the
    main selection's fit of the same effects where it has one. No screening: the few
    contenders are each fitted in full, and warm starts make a full fit cost little more
    than a screening fit (the per-evaluation overhead, not the rows, dominates). The gain
    floor is the absolute one: the contenders have beaten the main selection's, and a
    resample's noisier fit of 64 ring gains pays more for its own noise in the gain, which
    then fell below the relative floor in 6 of 10 resamples of an effect at 9 score SEs."""
    with one_thread():
        return [
            forward_backward(
                d,
                contenders,
                w,
                validation,
                k_max=k_max,
                refs=refs,
                z_accept=Z_RESAMPLE,
                warm=warm,
                screen_rows=None,
                floor=MIN_GAIN_NATS,
            ).labels
            for w in ws
        ]
