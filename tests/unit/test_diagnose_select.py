"""Choosing effects: lads/diagnose/{select,analysis,parallel,design}.py on synthetic tables.

The tables come from `make_table` of test_diagnose_localize (500 spatial groups, a per-group
random effect standing in for object reflectance); a hidden per-ring gain is written into the
real intensity so the right answer is known.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from lads.diagnose.data.table import BeamTable
from lads.diagnose.effects.c4_rings import odd_rings
from lads.diagnose.effects.c6_class_reflectance import one_class_scale
from lads.diagnose.effects.c11_azimuth_blockage import azimuth_spacing_deg
from lads.diagnose.effects.catalogue import candidates
from lads.diagnose.fit.bootstrap import group_multiplicity
from lads.diagnose.fit.design import group_index
from lads.diagnose.fit.from_table import paired_design, sim_log_variance
from lads.diagnose.fit.likelihood import BASE_NAMES, Model, nll_from_terms
from lads.diagnose.fit.model import Fit, directional_gain, fit, fit_best, initial_base
from lads.diagnose.fit.parallel import fit_models, fit_warm, map_fits, restrict
from lads.diagnose.selection.compare import (
    Comparison,
    by_groups,
    by_rows,
    compare_groups,
    row_gains,
)
from lads.diagnose.selection.select import (
    MIN_GAIN_NATS,
    SHORTLIST,
    SHORTLIST_CONFINED,
    Z_ACCEPT,
    Selection,
    _passes,
    gain_floor,
    reference_levels,
)
from lads.diagnose.selection.support import MIN_SUPPORT_GROUPS, crossfit_support, domain_rows
from lads.diagnose.verdict.ambiguity import ground_only_rule, resample_swaps
from lads.diagnose.verdict.analysis import (
    EffectReport,
    Settings,
    claim_with_sets,
    diagnose_design,
)
from lads.diagnose.verdict.intervals import ci95, interval95
from lads.diagnose.verdict.stability import effect_family
from tests.unit.test_diagnose_localize import make_table

QUICK = Settings(fit_rows=12000, resamples=4, bootstrap=4, jobs=1)


def with_ring_gains(table: BeamTable, sigma_ln: float, seed: int) -> tuple[BeamTable, np.ndarray]:
    """The table with real returns multiplied by exp(g_ring), g ~ N(0, sigma) centred."""
    rng = np.random.default_rng(seed)
    g = rng.normal(0.0, sigma_ln, table.sensor.n_rings)
    g -= g.mean()
    h = table.sensor.half_step
    scale = np.exp(g[table.ring.astype(np.int64)])
    i_real = np.where(np.isfinite(table.i_real), (table.i_real + h) * scale - h, np.nan)
    i_real = np.where(table.ret_sim, i_real, table.i_real)
    return dataclasses.replace(table, i_real=i_real.astype(np.float32)), g


@pytest.fixture(scope="module")
def ring_case():
    table, g = with_ring_gains(make_table(3, group_sd=0.25, noise=0.1), 0.15, seed=4)
    design = paired_design(table)
    return design, g, diagnose_design(design, np.random.default_rng(0), QUICK)


def test_per_ring_gains_under_object_noise_are_claimed_and_fitted(ring_case):
    _, g, dg = ring_case
    claimed = {r.effect.info.id: r for r in dg.effects if r.status == "claimed"}
    assert "C4" in claimed
    assert dg.verdict in ("effects_found", "ambiguous")
    est = np.asarray(claimed["C4"].params["ln_gain_by_ring"])
    # Each ring holds ~780 rows from ~40 surfaces: its gain is known to a few hundredths.
    assert np.corrcoef(est, g)[0, 1] > 0.9
    assert np.median(np.abs(est - g)) < 0.05


def test_alternatives_listed_fit_within_one_standard_error(ring_case):
    _, _, dg = ring_case
    for alt in dg.alternatives:
        assert abs(alt["delta_loss"]) <= alt["se"]


def test_held_out_improvement_is_reported_with_its_standard_error(ring_case):
    _, _, dg = ring_case
    gain = dg.heldout["test_gain_nats"]
    assert gain["delta"] > 3.0 * gain["se"] > 0.0
    assert dg.heldout["after"]["rmse_ln_i"] < dg.heldout["before"]["rmse_ln_i"]


def test_the_diagnosis_does_not_depend_on_the_number_of_jobs(ring_case):
    design, _, serial = ring_case
    parallel = diagnose_design(design, np.random.default_rng(0), dataclasses.replace(QUICK, jobs=2))
    assert parallel.frequencies == serial.frequencies
    assert np.array_equal(parallel.final.theta, serial.final.theta)
    for a, b in zip(parallel.effects, serial.effects, strict=True):
        assert a.ci95 == b.ci95


def test_the_directional_score_is_the_slope_of_each_rows_nll_toward_the_new_fit(ring_case):
    design, _, dg = ring_case
    rows = np.arange(0, len(design), 7)
    sub = design.subset(rows)
    new, old = dg.selection.fit, dg.selection.baseline
    start, end = old.row_terms(sub), new.row_terms(sub)
    score = directional_gain(start, end, sub)
    eps = 1e-6
    step = torch.full((len(sub),), eps, dtype=torch.float64)
    with torch.no_grad():
        moved = nll_from_terms(start.toward(end, step), sub).numpy()
    assert np.allclose(score, (old.row_nll(sub) - moved) / eps, rtol=1e-3, atol=1e-6)


def test_on_held_out_rows_the_score_has_twice_the_z_of_the_nll_gain():
    """A weak ring pattern fitted on half the groups, judged on the other half: the gain
    pays for the fit's own noise and is second order in the effect, the score is not."""
    table, _ = with_ring_gains(make_table(3, group_sd=0.25, noise=0.1), 0.05, seed=4)
    d = paired_design(table)
    groups = np.unique(d.group)
    train = np.flatnonzero(np.isin(d.group, groups[::2]))
    held = d.subset(np.flatnonzero(~np.isin(d.group, groups[::2])))
    w = np.zeros(len(d))
    w[train] = 1.0
    base = initial_base(d, train)
    model = Model([], float(d.ln_range.mean()), float(d.ln_sim.mean()))
    old = fit(model, d, w, base)
    (ring,) = [e for e in candidates(d) if e.info.id == "C4" and e.label == "C4"]
    new = fit_models([model.with_effect(ring)], d, w, base, old, 1)[0]
    c = by_rows(*row_gains(new, old, held), held.group)
    assert c.delta > 0.0
    assert 1.5 < c.z / (c.delta / c.se) < 3.0


def test_the_parameter_bootstrap_draws_whole_scans_before_their_tiles(ring_case):
    """A tile bootstrap keeps every scan in every replicate, so what differs between scans
    never varies; drawing the scans first leaves one out in almost every replicate (10
    scans: all are drawn with probability 10!/10^10 < 0.001), and a tile is always kept or
    dropped whole."""
    d = ring_case[0]
    rows = np.arange(len(d))
    scans = d.scan.numpy()
    n_scans = len(np.unique(scans))
    assert n_scans == 10
    rng = np.random.default_rng(1)
    missing = {False: 0, True: 0}
    for by_scan in (False, True):
        for _ in range(40):
            m = group_multiplicity(d, rows, rng, by_scan=by_scan)
            present = np.unique(scans[m > 0])
            missing[by_scan] += len(present) < n_scans
            for g in np.unique(d.group)[:50]:
                assert len(np.unique(m[d.group == g])) == 1
    assert missing[False] == 0
    assert missing[True] >= 38


def with_weak_rings(table: BeamTable, rings: list[int], ln_gain: float) -> BeamTable:
    """The table with the real returns of `rings` multiplied by exp(ln_gain)."""
    g = np.zeros(table.sensor.n_rings)
    g[rings] = ln_gain
    h = table.sensor.half_step
    scale = np.exp(g[table.ring.astype(np.int64)])
    i_real = np.where(
        table.ret_sim & np.isfinite(table.i_real), (table.i_real + h) * scale - h, table.i_real
    )
    return dataclasses.replace(table, i_real=i_real.astype(np.float32))


def test_rings_that_stand_out_from_the_others_at_the_same_range_are_picked_on_training_rows():
    table = make_table(3, group_sd=0.25, noise=0.1)
    weak = paired_design(with_weak_rings(table, [5, 40], -0.4))
    train = np.flatnonzero(np.isin(weak.group, np.unique(weak.group)[::2]))
    assert odd_rings(weak, train) == [5, 40]
    assert odd_rings(paired_design(table), train) == []  # no ring effect: no ring passes
    (few,) = [e for e in candidates(weak, train_rows=train) if e.label == "C4[few_rings]"]
    assert few.size == 2
    exported = few.export(np.array([-0.4, -0.4]))
    assert exported["rings"] == [5, 40]
    assert sum(exported["ln_gain_by_ring"]) == pytest.approx(0.0, abs=1e-12)  # like C4


def test_one_weak_ring_of_64_is_claimed_as_a_ring_gain_on_that_ring():
    """1.6 % of the rows: the full C4 would pay for 63 gains fitted to noise."""
    table = with_weak_rings(make_table(5, group_sd=0.25, noise=0.1), [17], -0.35)
    dg = diagnose_design(paired_design(table), np.random.default_rng(0), QUICK)
    (ring,) = [r for r in dg.effects if r.status == "claimed"]
    assert ring.effect.label == "C4[few_rings]"
    gains = np.asarray(ring.params["ln_gain_by_ring"])
    assert int(np.argmin(gains)) == 17
    assert gains[17] - np.median(gains) == pytest.approx(-0.35, abs=0.1)


def test_a_null_table_claims_nothing():
    design = paired_design(make_table(5, group_sd=0.25, noise=0.1))
    dg = diagnose_design(design, np.random.default_rng(0), QUICK)
    assert [r for r in dg.effects if r.status == "claimed"] == []
    assert dg.verdict == "no_missing_physics"
    assert dg.noise_model["kind"] == "homoscedastic"


def test_a_simulation_that_is_the_recording_claims_nothing():
    """Stored values are intervals whose likelihood peaks at their centre in ln space, so an
    exact copy still gains from tiny shifts; an exact copy has nothing missing."""
    table = make_table(5, group_sd=0.25, noise=0.1)
    stored = (np.round(table.i_sim / table.sensor.step) * table.sensor.step).astype(np.float32)
    # (without the rule this copy came out "ambiguous": an effect "beyond the catalogue")
    same = dataclasses.replace(table, i_sim=stored, i_real=stored, ret_real=table.ret_sim.copy())
    dg = diagnose_design(paired_design(same), np.random.default_rng(0), QUICK)
    assert dg.verdict == "no_missing_physics" and dg.effects == [] and dg.possible == []
    assert len(dg.reasons) == 1 and "within its resolution" in dg.reasons[0]
    # a copy a step off on some beams (a simulation rounding differently) is rounding too
    rng = np.random.default_rng(5)
    off = rng.random(stored.size) < 0.05
    step = np.zeros(stored.size)
    step[off] = table.sensor.step * rng.choice([-1, 1], int(off.sum()))
    near = stored + step  # (without the rule this came out "ambiguous", C2 at its bound)
    near = np.clip(near, 0.0, table.sensor.max_value).astype(np.float32)
    dg = diagnose_design(
        paired_design(dataclasses.replace(same, i_real=near)), np.random.default_rng(0), QUICK
    )
    assert dg.verdict == "no_missing_physics" and dg.effects == []


def test_point_noise_that_grows_with_range_is_a_noise_model_not_an_effect():
    table = make_table(5, group_sd=0.25, noise=0.05)
    rng = np.random.default_rng(11)
    h = table.sensor.half_step
    # sigma rises from ~0.05 at 5 m to ~0.5 at 100 m, zero mean in ln I: no bias to name.
    sd = 0.05 * (table.range_m / 5.0) ** 0.8
    scale = np.exp(rng.normal(0.0, 1.0, len(table)) * sd)
    i_real = np.where(
        table.ret_sim & np.isfinite(table.i_real), (table.i_real + h) * scale - h, table.i_real
    )
    noisy = dataclasses.replace(table, i_real=i_real.astype(np.float32))
    dg = diagnose_design(paired_design(noisy), np.random.default_rng(0), QUICK)
    assert dg.noise_model["kind"] == "heteroscedastic"
    assert dg.noise_model["range_slope"] > 0.1
    gain = dg.noise_model["heldout_gain_nats"]
    assert gain["delta"] > 3.0 * gain["se"]
    assert [r for r in dg.effects if r.status == "claimed"] == []


def test_simulated_values_stored_at_the_clip_are_left_out_of_a_paired_design():
    table = make_table(6, n_scans=2)
    top = table.sensor.max_value
    i_sim = table.i_sim.copy()
    i_sim[:50] = top
    design = paired_design(dataclasses.replace(table, i_sim=i_sim))
    assert not np.isin(np.arange(50), design.rows).any()
    assert len(design) == int((np.isfinite(table.i_sim) & table.ret_sim).sum()) - int(
        (table.ret_sim[:50] & np.isfinite(table.i_sim[:50])).sum()
    )


def _sums(design, ws, extra):
    """A stand-in task: each weighted sum over the rows it uses, like a fit's loss."""
    y = design.y.numpy()
    return [float((y[w > 0] * w[w > 0]).sum()) + float(y[extra].sum()) for w in ws]


def test_restricted_parts_keep_row_order_and_weights():
    design = paired_design(make_table(7, n_scans=2))
    rng = np.random.default_rng(0)
    ws = [
        np.where(rng.random(len(design)) < 0.1, rng.integers(1, 3, len(design)), 0).astype(float)
        for _ in range(3)
    ]
    extra = np.sort(rng.choice(len(design), 40, replace=False))
    part, part_ws, part_extra = restrict(design, ws, extra)
    assert np.all(np.diff(part.rows) > 0)
    assert np.array_equal(part.rows[part_extra], design.rows[extra])
    assert _sums(part, part_ws, part_extra) == _sums(design, ws, extra)
    assert map_fits(_sums, design, ws, extra, 1) == map_fits(_sums, design, ws, extra, 2)


def test_candidate_fits_do_not_depend_on_the_number_of_jobs(ring_case):
    design = ring_case[0]
    weights = np.zeros(len(design))
    weights[::7] = 1.0
    rows = np.flatnonzero(weights)
    base = initial_base(design, rows)
    empty = Model([], float(design.ln_range.mean()), float(design.ln_sim.mean()))
    models = [empty.with_effect(e) for e in candidates(design)[:5]]
    serial = fit_models(models, design, weights, base, None, 1)
    parallel = fit_models(models, design, weights, base, None, 2)
    for a, b in zip(serial, parallel, strict=True):
        assert a.model is b.model
        assert np.array_equal(a.theta, b.theta) and a.loss == b.loss


def test_a_simulated_zero_contributes_its_return_but_not_its_intensity():
    table = make_table(8, n_scans=2)
    i_sim = table.i_sim.copy()
    i_sim[:200] = 0.0
    base = paired_design(dataclasses.replace(table, i_sim=i_sim))
    zero = np.isin(base.rows, np.arange(200))
    assert not base.sim_ok.numpy()[zero].any() and base.sim_ok.numpy()[~zero].all()
    i_real = table.i_real.copy()
    i_real[:200] = np.where(np.isfinite(i_real[:200]), 0.9, np.nan)
    moved = paired_design(dataclasses.replace(table, i_sim=i_sim, i_real=i_real))
    model = Model([], 0.0, 0.0)
    theta = torch.tensor([0.0, -1.0, 0.0, 0.0, 3.0], dtype=torch.float64)
    with torch.no_grad():
        a, b = model.nll_rows(theta, base).numpy(), model.nll_rows(theta, moved).numpy()
    assert np.array_equal(a, b)


def test_rounding_variance_of_the_simulated_value_falls_with_its_level():
    step, h = 0.01, 0.005
    var = sim_log_variance(np.array([0.01, 0.02, 0.1, 0.5]), step, h)
    assert np.all(np.diff(var) < 0)
    # Far from 0, ln is locally linear: Var ~ (step / (i + h))^2 / 12.
    assert var[3] == pytest.approx((step / 0.505) ** 2 / 12.0, rel=1e-3)
    assert var[0] > 0.02


def test_an_effect_rejected_only_for_its_bound_is_reported_as_beyond_the_catalogue():
    from types import SimpleNamespace

    from lads.diagnose.selection.select import Selection, Step
    from lads.diagnose.verdict.analysis import _beyond_bounds

    empty = SimpleNamespace(model=SimpleNamespace(effects=[]))
    sel = Selection(fit=empty, baseline=empty)  # type: ignore[arg-type]
    sel.trace = [
        Step(1, "C2", 0.05, 0.01, -20.0, True, z=5.0),  # at a bound: beyond the catalogue
        Step(1, "C9", 0.02, 0.01, -20.0, True, z=2.0),  # z 2: not evidence of anything
        Step(1, "C1", 0.05, 0.01, -20.0, False, z=5.0),  # in range: an ordinary candidate
    ]
    assert _beyond_bounds(sel) == [("C2", 5.0)]


def with_bright_signs(table: BeamTable, ln_gain: float, seed: int) -> BeamTable:
    """6 rows of 24 object groups relabelled traffic-sign, real intensity x exp(ln_gain) /
    cos(incidence): a retro-reflector returns the same whatever the angle (catalogue C3r)."""
    rng = np.random.default_rng(seed)
    class_id = table.class_id.copy()
    groups = np.unique(table.group[~table.is_ground])
    for gid in rng.choice(groups, 24, replace=False):
        rows = np.flatnonzero((table.group == gid) & table.ret_sim)[:6]
        class_id[rows] = 81
    sign = class_id == 81
    h = table.sensor.half_step
    gain = np.exp(ln_gain) / table.cos_incidence
    brighter = np.minimum((table.i_real + h) * gain - h, table.sensor.max_value)
    i_real = np.where(sign & np.isfinite(table.i_real), brighter, table.i_real)
    names = {**table.class_names, 81: "traffic-sign"}
    return dataclasses.replace(
        table, class_id=class_id, class_names=names, i_real=i_real.astype(np.float32)
    )


def test_a_bright_rare_class_is_found_from_its_own_rows():
    """144 sign rows of 50 000: over all held-out rows the gain is within ~2 cluster SEs (the
    untouched groups dominate the SE), but on the sign rows it is consistent group by group."""
    table = with_bright_signs(make_table(6, group_sd=0.25, noise=0.1), 1.0, seed=1)
    design = paired_design(table)
    dg = diagnose_design(design, np.random.default_rng(0), QUICK)
    claimed = {r.effect.label: r for r in dg.effects if r.status == "claimed"}
    assert "C3r[traffic-sign]" in claimed
    assert abs(claimed["C3r[traffic-sign]"].params["ln_gain"] - 1.0) < 0.2
    step = next(s for s in dg.selection.trace if s.candidate == "C3r[traffic-sign]")
    assert step.support is not None and step.support.groups >= MIN_SUPPORT_GROUPS


def _sign_fits(ln_gain: float | None):
    """(design, baseline fit, fit with a sign reflectance scale (C6), training weights,
    held-out sign rows, sign class index) of a table whose signs are brighter by ln_gain
    (None: relabelled only, no effect). C6 nests the baseline (C3r's gain range does not)."""
    base_table = make_table(6, group_sd=0.25, noise=0.1)
    table = with_bright_signs(base_table, 0.0 if ln_gain is None else ln_gain, seed=1)
    if ln_gain is None:
        table = dataclasses.replace(table, i_real=base_table.i_real)
    d = paired_design(table)
    groups = np.unique(d.group)
    held_out = np.isin(d.group, groups[::2])  # every other group held out
    weights = np.where(held_out, 0.0, 1.0)
    sign = d.classes.index(81)
    c6 = one_class_scale(d, sign, "traffic-sign")
    start = initial_base(d, np.flatnonzero(weights))
    refs = reference_levels(d)
    baseline = fit_best(Model([], *refs), d, weights, start)
    with_c6 = fit_best(baseline.model.with_effect(c6), d, weights, start, baseline)
    signs = d.subset(np.flatnonzero(held_out & (d.class_index.numpy() == c6.class_index)))
    return d, baseline, with_c6, weights, signs, c6.class_index


def test_cross_fitting_adds_the_training_groups_of_a_rare_class_scored_out_of_sample():
    d, baseline, with_c6, weights, signs, k = _sign_fits(1.0)
    held = compare_groups(with_c6, baseline, signs)
    pooled = crossfit_support(with_c6, baseline, d, weights, signs, k, {})
    training_groups = np.unique(d.group[(weights > 0) & (d.class_index.numpy() == k)])
    assert pooled.groups == held.groups + len(training_groups)
    assert pooled.delta / pooled.se > held.delta / held.se
    # Without an effect the training groups, scored in sample, flatter the candidate (its
    # fit has seen their noise); scored by refits without their fold, they do not.
    d, baseline, with_c6, weights, signs, k = _sign_fits(None)
    rows = d.subset(np.flatnonzero((weights > 0) & (d.class_index.numpy() == k)))
    in_sample = compare_groups(with_c6, baseline, rows)
    out_of_sample = crossfit_support(with_c6, baseline, d, weights, signs, k, {})
    assert in_sample.delta > 0.0
    assert out_of_sample.delta < in_sample.delta
    assert out_of_sample.delta / out_of_sample.se < 2.0


def test_cross_fitted_folds_of_two_classes_do_not_share_the_incumbents_refits():
    d, baseline, with_c6, weights, signs, k = _sign_fits(1.0)
    other = int(np.bincount(d.class_index.numpy()[d.class_index.numpy() >= 0]).argmax())
    other_rows = d.subset(np.flatnonzero((weights == 0) & (d.class_index.numpy() == other)))
    shared: dict = {}
    crossfit_support(with_c6, baseline, d, weights, signs, k, shared)
    reused = crossfit_support(with_c6, baseline, d, weights, other_rows, other, shared)
    alone = crossfit_support(with_c6, baseline, d, weights, other_rows, other, {})
    assert reused == alone


def comparison(delta: float, se: float, groups: int) -> Comparison:
    """A held-out comparison whose directional score has the z of its gain."""
    return Comparison(delta, se, 0.0, groups, delta, se)


def test_a_class_confined_gain_passes_on_its_rows_only_with_enough_consistent_groups():
    overall = comparison(delta=0.004, se=0.002, groups=200)
    consistent = comparison(delta=0.5, se=0.05, groups=10)
    erratic = comparison(delta=0.5, se=0.15, groups=10)
    few = comparison(delta=0.5, se=0.08, groups=3)
    floor = MIN_GAIN_NATS
    assert not _passes(overall, False, Z_ACCEPT, floor)
    assert _passes(overall, False, Z_ACCEPT, floor, consistent)
    assert not _passes(overall, False, Z_ACCEPT, floor, erratic)  # t = 3.3 < t(9) bar of ~4.3
    assert not _passes(overall, False, Z_ACCEPT, floor, few)  # t = 6.3 < t(2) bar of ~19
    assert not _passes(overall, True, Z_ACCEPT, floor, consistent)  # at a bound
    losing = dataclasses.replace(overall, delta=-0.001)
    assert not _passes(losing, False, Z_ACCEPT, floor, consistent)  # other rows got worse
    assert not _passes(overall, False, Z_ACCEPT, 0.6, consistent)  # too small to matter
    # A score that passes over all rows does not carry a confined effect that loses on its
    # own rows: that gain came from the refitted baseline.
    strong = comparison(delta=0.005, se=0.001, groups=200)
    assert _passes(strong, False, Z_ACCEPT, floor)
    assert _passes(strong, False, Z_ACCEPT, floor, erratic)
    assert not _passes(strong, False, Z_ACCEPT, floor, comparison(-0.01, 0.003, 60))


def test_an_effect_is_accepted_on_its_directional_score_and_a_gain_above_the_floor():
    """The score's z is the test; the NLL gain must only beat the floor, whatever its z."""
    weak_gain = Comparison(
        delta=0.01, se=0.005, delta_bic=0.0, groups=100, score=0.04, score_se=0.01
    )
    assert weak_gain.z == pytest.approx(4.0)
    assert _passes(weak_gain, False, Z_ACCEPT, 0.005)
    assert not _passes(weak_gain, False, Z_ACCEPT, 0.02)  # gain below the floor
    chance = dataclasses.replace(weak_gain, delta=0.05, score=0.02)  # large gain, z 2
    assert not _passes(chance, False, Z_ACCEPT, 0.005)
    assert gain_floor(1.2) == pytest.approx(0.006)  # 0.5 % of the baseline deviance
    assert gain_floor(0.1) == MIN_GAIN_NATS  # never below the absolute floor


def test_the_floor_is_a_share_of_the_deviance_whatever_the_noise_level():
    """Half the deviance is ~0.5 z^2 a row for a well-specified fit at any sigma; the NLL
    carries ln sigma (and a coarse encoding's interval probabilities) and would move the
    floor with the noise level."""
    half, nll = [], []
    for noise in (0.05, 0.4):
        d = paired_design(make_table(2, noise=noise, drop=lambda r: np.zeros(r.shape)))
        rows = np.arange(len(d))
        model = Model([], float(d.ln_range.mean()), float(d.ln_sim.mean()), False)
        terms = fit(model, d, np.ones(len(d)), initial_base(d, rows)).row_terms(d)
        half.append(float(terms.half_deviance(d).mean()))
        nll.append(float(terms.nll(d).mean()))
    assert all(0.3 < h < 0.7 for h in half)
    assert nll[1] - nll[0] > 1.0
    assert gain_floor(half[1]) == pytest.approx(gain_floor(half[0]), rel=0.25)


def test_class_rows_count_each_group_once():
    """Nine tiles, every one gaining, tile sizes 1-24 and gains 7-48 nats/row (a retro gain
    clipped in some tiles): the row-weighted ratio's t stays below the t(8) bar, each tile
    counted once clears it. One big tile with a chance gain among null tiles does not."""
    sizes = np.array([1, 8, 1, 11, 9, 5, 4, 24, 2])
    per_row = np.array([48.0, 43.0, 6.7, 9.1, 40.0, 41.0, 39.6, 7.9, 44.0])
    group = np.repeat(np.arange(9), sizes)
    gain = np.repeat(per_row, sizes)
    overall = comparison(delta=0.01, se=0.005, groups=200)
    grouped = by_groups(gain, group)
    assert grouped.groups == 9 and np.isclose(grouped.delta, per_row.mean())
    assert _passes(overall, False, Z_ACCEPT, MIN_GAIN_NATS, grouped)
    assert not _passes(overall, False, Z_ACCEPT, MIN_GAIN_NATS, by_rows(gain, gain, group))

    rng = np.random.default_rng(0)
    sizes = np.r_[400, np.full(39, 10)]
    group = np.repeat(np.arange(40), sizes)
    gain = rng.normal(0.0, 0.05, sizes.sum())
    gain[group == 0] += 0.05  # one large tile that happens to gain
    assert not _passes(overall, False, Z_ACCEPT, MIN_GAIN_NATS, by_groups(gain, group))


def test_effects_are_accepted_on_full_fits_after_a_screening_pass(ring_case):
    _, _, dg = ring_case
    trace = dg.selection.trace
    assert any(s.screened for s in trace)  # most candidates are only screened...
    assert all(not s.screened for s in trace if s.accepted)  # ...the winner never is
    for step in {s.step for s in trace}:
        full = [s for s in trace if s.step == step and not s.screened]
        assert 1 <= len(full) <= SHORTLIST + SHORTLIST_CONFINED


def test_of_candidates_within_one_paired_se_the_one_with_fewest_parameters_is_accepted():
    """A 64-parameter effect out-gains a 1-parameter one by less than the paired SE of their
    difference: the simpler one is taken. A clear winner keeps its place however large."""
    from types import SimpleNamespace

    from lads.diagnose.selection.select import _simplest_within_one_se

    rng = np.random.default_rng(3)
    group = np.repeat(np.arange(100), 20)
    noise = rng.normal(0.0, 0.3, group.size)

    def candidate(size: int, nll: np.ndarray, delta: float):
        fit = SimpleNamespace(row_nll=lambda d: nll, model=SimpleNamespace(size=size), loss=0.0)
        eff = SimpleNamespace(size=size)
        return (eff, fit, Comparison(delta, 0.01, 0.0, 100), False, None)

    sub = SimpleNamespace(group=group, group_index=group_index(group))
    rings = candidate(64, 1.0 - 0.005 + noise, 0.095)
    law = candidate(1, 1.0 + noise + rng.normal(0.0, 0.3, group.size), 0.090)
    assert _simplest_within_one_se([rings, law], sub) is law  # type: ignore[arg-type]
    clear = candidate(64, 1.0 - 0.2 + noise, 0.29)
    assert _simplest_within_one_se([clear, law], sub) is clear  # type: ignore[arg-type]


def test_the_oren_nayar_incidence_law_is_lambert_at_zero_roughness_and_brightens_grazing():
    design = paired_design(make_table(8, n_scans=2))
    (on,) = [e for e in candidates(design) if e.label == "C3[oren_nayar]"]
    assert on.info.id == "C3"
    zero = on.ln_term(torch.tensor([0.0], dtype=torch.float64), design)
    assert torch.all(zero == 0.0)
    s2 = 0.3**2
    a, b = 1 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)
    term = on.ln_term(torch.tensor([0.3], dtype=torch.float64), design).numpy()
    cos = np.maximum(design.cos.numpy(), 0.05)  # grazing normals are capped like ln cos
    ok = design.normal_ok.numpy()
    expected = np.log(a + b * (1 - cos**2) / cos)
    assert np.allclose(term[ok], expected[ok])
    assert term[ok][cos[ok] < 0.2].min() > 0.0 > term[ok][cos[ok] > 0.99].max()


def test_ring_offsets_leave_a_common_offset_to_the_encoding():
    design = paired_design(make_table(8, n_scans=2))
    (c4o,) = [e for e in candidates(design) if e.label == "C4o"]
    n = c4o.size
    spread = torch.tensor(np.tile([0.02, -0.02], n // 2), dtype=torch.float64)
    common = torch.full((n,), 0.02, dtype=torch.float64)
    assert float(c4o.penalty(spread)) == pytest.approx(0.0, abs=1e-12)
    # One common step costs more than any held-out gain an effect is accepted for.
    assert float(c4o.penalty(common)) > 1.0


def test_a_warm_start_from_the_same_effects_in_another_order_reaches_the_same_fit(ring_case):
    design = ring_case[0]
    weights = np.zeros(len(design))
    weights[::5] = 1.0
    base = initial_base(design, np.flatnonzero(weights))
    pool = {e.label: e for e in candidates(design)}
    empty = Model([], float(design.ln_range.mean()), float(design.ln_sim.mean()))
    one = empty.with_effect(pool["C4"]).with_effect(pool["C1"])
    other = empty.with_effect(pool["C1"]).with_effect(pool["C4"])
    cold = fit_warm(one, design, weights, base, None)
    warm = fit_warm(other, design, weights, base, None, {one.key: cold})
    assert other.key == one.key
    assert warm.loss == pytest.approx(cold.loss, abs=1e-6)
    assert np.allclose(warm.effect_params("C4"), cold.effect_params("C4"), atol=1e-3)


def test_a_parameter_interval_is_never_narrower_than_its_resolution_floor():
    samples = [{"start_deg": 143.1 + 0.01 * k, "a": 0.4 + 0.001 * k} for k in range(40)]
    ci = ci95({"start_deg": 143.3, "a": 0.42}, samples, {"start_deg": 0.5})
    assert ci["start_deg"][0] == pytest.approx(142.8) and ci["start_deg"][1] == pytest.approx(143.8)
    # Without a floor: the samples' 95 % interval, read at order-statistic positions.
    assert ci["a"] == pytest.approx([0.400025, 0.438975])


def test_a_95_percent_interval_of_40_replicates_holds_95_percent_of_further_draws():
    rng = np.random.default_rng(5)
    draws = rng.standard_normal((20000, 41))
    lo, hi = interval95(draws[:, :40].T)
    inside = np.mean((draws[:, 40] >= lo) & (draws[:, 40] <= hi))
    assert inside == pytest.approx(0.95, abs=0.01)
    # numpy's default positions give the 2nd order statistics: about 90 %.
    lo7, hi7 = np.percentile(draws[:, :40], [2.5, 97.5], axis=1)
    assert np.mean((draws[:, 40] >= lo7) & (draws[:, 40] <= hi7)) < 0.92


def test_the_azimuth_spacing_is_the_median_step_between_returns_of_a_ring(ring_case):
    design = ring_case[0]
    spacing = azimuth_spacing_deg(design)
    scan0 = (design.scan.numpy() == 0) & (design.ring.numpy() == 0)
    az = np.sort(design.azimuth_deg.numpy()[scan0])
    assert 0.0 < spacing <= 360.0 / max(scan0.sum() - 1, 1) * 3.0
    assert spacing == pytest.approx(float(np.median(np.diff(az)[np.diff(az) > 0])), rel=0.5)


def _selection_of(design, labels):
    pool = {e.label: e for e in candidates(design)}
    model = Model([pool[k] for k in labels], 0.0, 0.0)
    fit = Fit(model, np.zeros(model.size), 0.0, True)
    return Selection(fit, fit)


def test_on_ground_only_data_exponent_incidence_ring_gains_and_gamma_are_one_ambiguity_set():
    table = make_table(7, group_sd=0.25, noise=0.1)
    ground_only = paired_design(table.take(table.is_ground))
    reasons: list[str] = []
    sets = ground_only_rule(ground_only, _selection_of(ground_only, ["C3"]), reasons)
    assert [s["ids"] for s in sets] == [["C1", "C3", "C4", "C9"]]
    assert "off the ground" in reasons[0]
    # An encoding gamma scales ln I_sim, which on flat ground is a function of range too.
    gamma = ground_only_rule(ground_only, _selection_of(ground_only, ["C9"]), [])
    assert [s["ids"] for s in gamma] == [["C1", "C3", "C4", "C9"]]
    # With walls and objects in the data (half the groups here) the terms are separable,
    # and an effect outside the ground identities never raises the rule.
    mixed = paired_design(table)
    assert ground_only_rule(mixed, _selection_of(mixed, ["C3"]), []) == []
    assert ground_only_rule(ground_only, _selection_of(ground_only, ["C5"]), []) == []


def test_parametrisations_of_one_effect_share_a_family_and_classes_do_not():
    design = paired_design(make_table(7, group_sd=0.25, noise=0.1))
    fam = {e.label: effect_family(e) for e in candidates(design)}
    assert fam["C3"] == fam["C3[oren_nayar]"] == ("C3", None)
    per_class = [k for k in fam if k.startswith("C6[")]
    assert len({fam[k] for k in per_class}) == len(per_class) >= 2


def test_an_effect_is_claimed_when_its_ambiguity_set_is_stable_though_it_alone_is_not():
    design = paired_design(make_table(7, group_sd=0.25, noise=0.1))
    pool = {e.label: e for e in candidates(design)}
    c1 = EffectReport(pool["C1"], {}, {}, 0.5, "possible")
    c6 = EffectReport(pool["C6"], {}, {}, 0.4, "possible")
    sets = [{"ids": ["C1", "C5"]}]
    # Every resample chose a range law, half of them as an exponent, half as attenuation;
    # the class scale has no ambiguity set and stays possible.
    chosen = [{"C1"}] * 5 + [{"C5"}] * 4 + [{"C5", "C6"}]
    reasons = claim_with_sets([c1, c6], sets, chosen)
    assert c1.status == "claimed" and c6.status == "possible"
    assert "['C1', 'C5']" in reasons[0] and "100%" in reasons[0]
    # A set chosen in 6 of 10 resamples does not make a claim.
    c1.status = "possible"
    assert claim_with_sets([c1], sets, [{"C1"}] * 3 + [{"C5"}] * 3 + [set()] * 4) == []
    assert c1.status == "possible"


def test_a_parameter_no_fitted_row_informs_is_flagged_and_gets_the_catalogue_range():
    design = paired_design(make_table(7, group_sd=0.25, noise=0.1))
    pool = {e.label: e for e in candidates(design)}
    scaled = [k for k in pool if k.startswith("C6[")][:2]
    absent, present = pool[scaled[0]], pool[scaled[1]]
    weights = (design.class_index.numpy() != absent.class_index).astype(np.float64)
    base = initial_base(design, np.flatnonzero(weights))
    empty = Model([], float(design.ln_range.mean()), float(design.ln_sim.mean()))
    fitted = fit_warm(empty.with_effect(absent).with_effect(present), design, weights, base, None)
    flat = fitted.flat_parameters(design, weights)
    assert flat == {absent.label: list(absent.names)}


def test_an_effect_confined_by_its_fit_is_also_tested_on_the_rows_it_acts_on():
    # A blocked sector is a few of the held-out tiles; its test reads the rows in the
    # sector the training fit chose, the other tiles say nothing about it.
    design = paired_design(make_table(21))
    pool = {e.label: e for e in candidates(design)}
    c11 = pool["C11"]
    model = Model([c11], 0.0, 0.0)
    theta = np.concatenate([np.zeros(len(BASE_NAMES)), [350.0, 30.0, 0.5, 0.1]])  # wraps 0
    sub = domain_rows(design, c11, Fit(model, theta, 0.0, True))
    assert sub is not None
    az = sub.azimuth_deg.numpy()
    assert np.all((az >= 350.0) | (az < 20.0))
    inside = (design.azimuth_deg.numpy() >= 350.0) | (design.azimuth_deg.numpy() < 20.0)
    assert len(sub) == int(inside.sum())
    # Effects that act everywhere, or on a class, have no such domain.
    c5 = pool["C5"]
    alpha = np.concatenate([np.zeros(len(BASE_NAMES)), [0.01]])
    assert domain_rows(design, c5, Fit(Model([c5], 0.0, 0.0), alpha, 0.0, True)) is None


def test_resamples_that_swap_a_selected_effect_for_another_make_an_ambiguity_set():
    pool = candidates(paired_design(make_table(22)))
    family = {e.label: effect_family(e) for e in pool}
    split = [["C2", "C1"]] * 5 + [["C2", "C5"]] * 5
    sets = resample_swaps(["C2", "C1"], split, pool, family, [])
    assert [s["ids"] for s in sets] == [["C1", "C5"]]
    assert "50%" in sets[0]["reason"]
    # Chosen instead in 2 of 10: the selected effect is stable, no set.
    assert (
        resample_swaps(["C2", "C1"], [["C2", "C1"]] * 8 + [["C2", "C5"]] * 2, pool, family, [])
        == []
    )
    # Together in fewer than 7 of 10: the mismatch itself is unstable, not its form.
    sparse = [["C1"]] * 3 + [["C5"]] * 3 + [[]] * 4
    assert resample_swaps(["C1"], sparse, pool, family, []) == []
    # A set the held-out swap test already listed is not repeated.
    known = [{"ids": ["C1", "C5"]}]
    assert resample_swaps(["C2", "C1"], split, pool, family, known) == []
    # Two forms of one effect are one answer, not an ambiguity.
    forms = [["C3"]] * 5 + [["C3[oren_nayar]"]] * 5
    assert resample_swaps(["C3"], forms, pool, family, []) == []
