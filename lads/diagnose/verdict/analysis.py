"""One diagnosis of a design: selection, stability, ambiguity, uncertainty and held-out
metrics (docs/diagnose.md §5.4-5.7). Pure computation on a `Design`; no files.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.stats import wasserstein_distance

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.terms import Effect, candidates
from lads.diagnose.fit.bootstrap import bootstrap_params, bootstrap_weights
from lads.diagnose.fit.design import Design, evenly_spaced
from lads.diagnose.fit.model import BASE_NAMES, Fit, Model, fit, fit_best, initial_base
from lads.diagnose.fit.parallel import map_fits, one_thread
from lads.diagnose.selection.grouping import Split, fit_weights, split_groups
from lads.diagnose.selection.select import (
    CLAIM_FREQUENCY,
    MIN_GAIN_NATS,
    POSSIBLE_FREQUENCY,
    Z_ACCEPT,
    Z_RESAMPLE,
    Selection,
    compare,
    compare_on,
    forward_backward,
    reference_levels,
)
from lads.diagnose.verdict.ambiguity import (
    ground_only_rule,
    range_band_rule,
    resample_swaps,
    separating_data,
    swap_ambiguity,
)
from lads.diagnose.verdict.point_noise import point_noise

NOISE_MIN_SLOPE = CONFIG.verdict.noise_min_slope
# The neighbour-difference slopes (point_noise.py) that matter: shot noise has 1 per ln R
# (-0.5 per ln I); with homoscedastic noise the estimator still reads a small slope (pairs
# that straddle two surfaces, the rounding model), up to about a third on piecewise-planar
# ground, so the bar sits between that and shot noise.
POINT_NOISE_MIN_SLOPE = CONFIG.verdict.point_noise_min_slope
Z_TEST = CONFIG.verdict.z_test


@dataclass(frozen=True)
class Settings:
    """Effort knobs of a diagnosis.

    Attributes:
        fit_rows: training rows per fit (a uniform subsample; groups all stay represented).
        resamples: group-bootstrap reruns of the selection (stability, §5.5 step 7).
        selection_rows: validation rows the main selection scores on (every k-th; all of
            them when fewer). Its SEs are cluster SEs: rows of one 10 m tile share their
            surfaces, so rows beyond a few hundred thousand add little but time.
        resample_rows: the same for the resamples, which ask only whether the main
            selection's effects win again (fewer rows suffice).
        bootstrap: group-bootstrap refits of the final model (95 % percentile CIs).
        k_max: most effects selected.
        jobs: processes for the resamples and bootstrap refits (results do not depend on it).

    fit_rows must leave every one of 64 per-ring gains several surfaces, or the selection
    flips between resamples. How these row counts were chosen, and on which cases:
    benchmarks/results/diagnose_case_notes.md.
    """

    fit_rows: int = 15000
    resamples: int = 10
    resample_rows: int = 60_000
    selection_rows: int = 200_000
    bootstrap: int = 40
    k_max: int = 4
    jobs: int = 2


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

    # Stability: rerun the selection on group-bootstrap resamples of the training groups,
    # over the candidates that earned a full fit and passed the resamples' bar at some
    # forward step (a score z > Z_RESAMPLE and a gain above the floor: the rest never win),
    # and at most one step beyond the main selection: the resamples ask whether the same
    # effects win, which costs a full selection each.
    strong = {s.candidate for s in selection.trace if not s.screened
              and s.z > Z_RESAMPLE and s.delta_loss > selection.floor}  # fmt: skip
    phase(PHASES[1])
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
    chosen_sets = map_fits(_resample_labels, d, ws, scoring, settings.jobs,
                           contenders, k_resample, reference_levels(d), warm)  # fmt: skip
    # Parametrisations of one effect (C3 as cos^p or as Oren-Nayar roughness) are one answer
    # to "is this effect there": a resample that picks the other form still selects it. Counted
    # apart, an incidence law chosen in 10 of 10 resamples, 6 times as Oren-Nayar and 4 as
    # cos^p, was reported as "possible" twice instead of claimed once.
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

    # Final model on train + validation, bootstrap CIs on the same rows.
    phase(PHASES[2])
    fit_all = np.concatenate([split.train, split.validation])
    w_all = fit_weights(len(d), fit_all, settings.fit_rows * 2, rng)
    base = initial_base(d, fit_all)
    final = fit_best(selection.fit.model, d, w_all, base, selection.fit)
    boot = bootstrap_params(final, d, fit_all, settings.fit_rows, settings.bootstrap, rng,
                            settings.jobs)  # fmt: skip

    effects, possible = [], []
    flat = final.flat_parameters(d, w_all)
    for e, sl in zip(final.model.effects, final.model.slices(), strict=True):
        theta = final.theta[sl]
        params = e.export(theta)
        samples = np.array([e.export(b[sl]) for b in boot], dtype=object)
        ci = _ci(params, list(samples), e.extra.get("ci_floor", {}))
        unidentified = [n for n in flat.get(e.label, []) if n in params]
        for n in unidentified:
            # Anywhere in the catalogue range fits as well: that range is the interval.
            j = e.names.index(n)
            ci[n] = [float(e.lower[j]), float(e.upper[j])]
        f = fam_freq.get(e.label, 0.0)
        status = "claimed" if f >= CLAIM_FREQUENCY else "possible"
        effects.append(EffectReport(e, params, ci, f, status, _sample_arrays(params, samples),
                                    unidentified))  # fmt: skip
    listed = {effect_family(e) for e in final.model.effects}
    for e in sorted(pool, key=lambda e: -freq.get(e.label, 0.0)):
        f = fam_freq.get(e.label, 0.0)
        if family[e.label] not in listed and f >= POSSIBLE_FREQUENCY:
            listed.add(family[e.label])
            possible.append({"id": e.info.id, "key": e.info.key, "label": e.label,
                             "selection_frequency": f})  # fmt: skip

    phase(PHASES[3])
    alternatives, sets = swap_ambiguity(d, selection, pool, weights, split, settings.jobs)
    reasons: list[str] = []
    sets += range_band_rule(d, selection, reasons)
    sets += resample_swaps(selection.labels, chosen_sets, pool, family, sets)
    sets += ground_only_rule(d, selection, reasons)
    if settings.resamples > 0:
        ids_by_label = {e.label: e.info.id for e in pool}
        chosen_ids = [{ids_by_label[label] for label in labels} for labels in chosen_sets]
        reasons += claim_with_sets(effects, sets, chosen_ids)
    noise = _noise_model(final, d, boot, selection, weights, split)
    heldout = heldout_metrics(d, split.test, selection.baseline, final)
    claimed = [r for r in effects if r.status == "claimed"]
    ambiguous_ids = {i for s in sets for i in s["ids"]}
    beyond = _beyond_bounds(selection)
    reasons += [f"{label} would improve the held-out fit by {z:.1f} SE but a parameter sits at "
                "its catalogue bound: the mismatch it describes is larger than the catalogue "
                "allows for it, or another effect is missing" for label, z in beyond]  # fmt: skip
    test_gain = compare(final, selection.baseline, d, split.test, 1.0, 1.0)
    heldout["test_gain_nats"] = {"delta": test_gain.delta, "se": test_gain.se}
    if not claimed and effects and test_gain.delta > Z_TEST * test_gain.se:
        # Something real is missing (the test groups say so) but no single effect is
        # selected stably enough to name: the data cannot decide which.
        verdict = "ambiguous"
        reasons.append(
            f"the selected effects improve the test groups by {test_gain.delta:.4f} nats/row "
            f"({test_gain.delta / max(test_gain.se, 1e-12):.1f} SE) but were chosen in fewer "
            "than 70 % of the resamples"
        )
    elif not claimed and beyond:
        # Held-out data say something is missing, the catalogue cannot fit it in range.
        verdict = "ambiguous"
    elif not claimed:
        verdict = "no_missing_physics"
        if possible:
            reasons.append("effects were selected in fewer than 70 % of the resamples")
    elif all(r.effect.info.id in ambiguous_ids for r in claimed):
        verdict = "ambiguous"
    else:
        verdict = "effects_found"
    return Diagnosis(split, selection, final, effects, possible, alternatives, sets, noise,
                     heldout, verdict, reasons, freq)  # fmt: skip


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
                reasons.append(f"{r.effect.label} is claimed with its ambiguity set "
                               f"{sorted(group)}: one of them was chosen in {hit:.0%} of the "
                               "resamples")  # fmt: skip
                break
    return reasons


def effect_family(e: Effect) -> tuple[str, str | None]:
    """(catalogue ID, class) of an effect: its parametrisations share it, classes do not."""
    return e.info.id, e.class_name


def _beyond_bounds(sel: Selection) -> list[tuple[str, float]]:
    """(label, z) of unselected candidates rejected only for a parameter at a bound."""
    chosen = set(sel.labels)
    best: dict[str, float] = {}
    for s in sel.trace:
        if s.at_bound and s.candidate not in chosen:
            if s.z > Z_ACCEPT and s.delta_loss > sel.floor:
                best[s.candidate] = max(s.z, best.get(s.candidate, 0.0))
    return sorted(best.items(), key=lambda kv: -kv[1])


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
        return [forward_backward(d, contenders, w, validation, k_max=k_max, refs=refs,
                                 z_accept=Z_RESAMPLE, warm=warm, screen_rows=None,
                                 floor=MIN_GAIN_NATS).labels
                for w in ws]  # fmt: skip


def _ci(
    params: dict[str, Any], samples: list[dict[str, Any]], floor: dict[str, float] | None = None
) -> dict[str, Any]:
    """95 % percentile intervals of `samples`; a scalar's interval spans at least
    `floor[name]` either side of its estimate (a resolution the bootstrap cannot see)."""
    out: dict[str, Any] = {}
    floor = floor or {}
    for name, value in params.items():
        vals = [s[name] for s in samples if name in s]
        if not vals:
            out[name] = None
            continue
        if isinstance(value, list):
            arr = np.array([v for v in vals if len(v) == len(value)], dtype=np.float64)
            if arr.size == 0:
                out[name] = None
                continue
            lo, hi = interval95(arr)
            out[name] = [[float(a), float(b)] for a, b in zip(lo, hi, strict=True)]
        else:
            lo, hi = interval95(np.asarray(vals, dtype=np.float64))
            pad = floor.get(name, 0.0)
            out[name] = [float(min(lo, value - pad)), float(max(hi, value + pad))]
    return out


def interval95(samples: npt.NDArray[np.float64]) -> tuple[Any, Any]:
    """The 2.5 and 97.5 % points of (B, ...) bootstrap `samples` along axis 0, read at
    order-statistic positions q (B + 1) (Hyndman & Fan type 6).

    A further draw from the same distribution falls between the k-th smallest and k-th
    largest of B draws with probability (B + 1 - 2k) / (B + 1). numpy's default positions
    q (B - 1) + 1 put the bounds near the 2nd order statistics at B = 40: an interval that
    covers 90 %, not 95 %, however good the bootstrap. Type 6 puts them at k = 1.025."""
    lo, hi = np.percentile(samples, [2.5, 97.5], axis=0, method="weibull")
    return lo, hi


def _sample_arrays(params: dict[str, Any], samples: Any) -> dict[str, npt.NDArray[np.float64]]:
    out = {}
    for name, value in params.items():
        if not isinstance(value, list):
            out[name] = np.array([s[name] for s in samples], dtype=np.float64)
    return out


def _noise_model(
    final: Fit,
    d: Design,
    boot: npt.NDArray[np.float64],
    sel: Selection,
    weights: npt.NDArray[np.float64],
    split: Split,
) -> dict[str, Any]:
    """The fitted noise of ln I: sigma and its slopes in ln R and ln I_sim, with CIs.

    "heteroscedastic" is a held-out verdict like any effect's: against the selected model
    refitted with constant sigma on the same training rows, the directional score toward the
    sloped sigma must exceed Z_ACCEPT cluster SEs on the held-out groups, and a slope must be
    large enough to matter (NOISE_MIN_SLOPE). A bootstrap z of the slope alone would miss
    real slopes: the object-level spread every surface shares dilutes the slope of ln
    sigma, not its likelihood gain.
    """
    th = final.theta
    out: dict[str, Any] = {
        "form": "ln sigma = ln_sigma + range_slope (ln R - m_R) + level_slope (ln I_sim - m_I)",
        "sigma_ln_i": float(math.exp(th[1])),
        "range_slope": float(th[2]),
        "level_slope": float(th[3]),
        "return_probability": float(1.0 / (1.0 + math.exp(-th[4]))),
        # Real values stored at a clip below the encoding's maximum are censored (design.py).
        "real_clip_level": d.real_clip,
    }
    if boot.shape[0] >= 5:
        for i, name in ((2, "range_slope"), (3, "level_slope")):
            lo, hi = interval95(boot[:, i])
            out[f"{name}_ci95"] = [float(lo), float(hi)]
    het = sel.fit
    flat = Model(list(het.model.effects), het.model.ln_range_ref, het.model.ln_sim_ref,
                 heteroscedastic=False)  # fmt: skip
    start = het.theta.copy()
    start[2:4] = 0.0
    hom = fit(flat, d, weights, start)
    held_out = np.concatenate([split.validation, split.test])
    c = compare_on(het, hom, d.subset(held_out), 1.0, 1.0)
    out["heldout_gain_nats"] = {"delta": c.delta, "se": c.se}
    big = max(abs(th[2]), abs(th[3])) > NOISE_MIN_SLOPE
    out["heldout_gain_nats"]["z"] = c.z
    total = "heteroscedastic" if big and c.z > Z_ACCEPT else "homoscedastic"
    mu = final.predictions(d)[0]
    fit_rows = np.concatenate([split.train, split.validation])
    refs = (final.model.ln_range_ref, final.model.ln_sim_ref)
    out["point_noise"] = point_noise(d, mu, fit_rows, split.test, *refs, POINT_NOISE_MIN_SLOPE,
                                     Z_ACCEPT)  # fmt: skip
    # Either test may see it: the total sigma a noise that every surface's own reflectance
    # does not swamp, the neighbour differences one that it does (point_noise.py).
    hetero = total == "heteroscedastic" or out["point_noise"]["kind"] == "heteroscedastic"
    out["kind"] = "heteroscedastic" if hetero else "homoscedastic"
    return out


def heldout_metrics(
    d: Design, rows: npt.NDArray[np.int64], baseline: Fit, final: Fit
) -> dict[str, Any]:
    """Metrics on the test groups: the simulation as is, the baseline fit and the final fit."""
    sub = d.subset(rows)
    # Intensity errors on returns stored clear of the quantisation floor and the clip: below
    # it the stored value is an interval, and an error in ln I would measure the rounding.
    ret = sub.fits_intensity & (sub.censor.numpy() == 0)
    y = sub.y.numpy()
    out: dict[str, Any] = {
        "rows": int(len(sub)),
        "groups": int(len(np.unique(sub.group))),
        "intensity_rows": int(ret.sum()),
    }
    out["simulation"] = _intensity_metrics(y[ret], sub.ln_sim.numpy()[ret], None, sub, ret)
    for name, f in (("before", baseline), ("after", final)):
        mu_np, sigma_np, p_np = f.predictions(sub)
        m = _intensity_metrics(y[ret], mu_np[ret], sigma_np[ret], sub, ret)
        if sub.paired:
            obs = sub.returned.numpy().astype(np.float64)
            pc = np.clip(p_np, 1e-9, 1 - 1e-9)
            m["dropout_brier"] = float(np.mean((pc - obs) ** 2))
            m["dropout_log_loss"] = float(-np.mean(obs * np.log(pc) + (1 - obs) * np.log(1 - pc)))
        m["nll"] = float(np.mean(f.row_nll(sub)))
        out[name] = m
    b, a = out["before"], out["after"]
    if b["rmse_ln_i"] and a["rmse_ln_i"] is not None:
        # Share of the baseline's mean squared ln I error that the effects remove.
        out["explained_share"] = float(1.0 - (a["rmse_ln_i"] / b["rmse_ln_i"]) ** 2)
    return out


def _intensity_metrics(
    y: npt.NDArray[np.float64],
    mu: npt.NDArray[np.float64],
    sigma: npt.NDArray[np.float64] | None,
    sub: Design,
    ret: npt.NDArray[np.bool_],
) -> dict[str, Any]:
    err = y - mu
    if y.size == 0:
        return {"rmse_ln_i": None, "mae_ln_i": None, "r2_ln_i": None}
    ss_tot = float(((y - y.mean()) ** 2).sum())
    out: dict[str, Any] = {
        "rmse_ln_i": float(np.sqrt(np.mean(err**2))),
        "mae_ln_i": float(np.mean(np.abs(err))),
        "median_abs_ln_i": float(np.median(np.abs(err))),
        "r2_ln_i": float(1.0 - (err**2).sum() / ss_tot) if ss_tot > 0 else None,
    }
    # Per-class W1 between real ln I and the model's predictive draws (mu + sigma z).
    cls = sub.class_index.numpy()[ret]
    rng = np.random.default_rng(0)
    draws = mu + (sigma if sigma is not None else 0.0) * rng.standard_normal(mu.size)
    w1: dict[str, float] = {}
    for ci, name in enumerate(sub.class_names):
        sel = cls == ci
        if sel.sum() >= 30:
            w1[name] = float(wasserstein_distance(y[sel], draws[sel]))
    if not w1 and y.size >= 30:
        w1["all"] = float(wasserstein_distance(y, draws))
    out["w1_ln_i_by_class"] = w1
    return out


__all__ = ["BASE_NAMES", "Diagnosis", "EffectReport", "Settings", "diagnose_design",
           "heldout_metrics", "separating_data"]  # fmt: skip
