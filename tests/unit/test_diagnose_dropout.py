"""Dropout effects: the D1 detection threshold (lads/diagnose/{model,effects,design}.py).

A threshold on the predicted power (the catalogue's P(ret) = Phi((mu - ln_tau) / s)) and one
on the measured value (Tobit) are both D1; the fit tells them apart by latent_share and
recovers s even when it is narrower than the intensity noise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.special import ndtr

from lads.diagnose.data.table import BeamTable
from lads.diagnose.effects.catalogue import candidates
from lads.diagnose.fit.from_table import paired_design
from lads.diagnose.fit.likelihood import Model
from lads.diagnose.fit.model import fit_best, initial_base
from tests.unit.test_diagnose_localize import make_table

LN_TAU, S = -2.5, 0.2


def with_threshold(table: BeamTable, on_measured: bool, seed: int) -> BeamTable:
    """Real returns kept with Phi((L - LN_TAU) / S), L the simulated or the real ln power."""
    h = table.sensor.half_step
    power = table.i_real if on_measured else table.i_sim
    z = (np.log(np.nan_to_num(power, nan=0.0) + h) - LN_TAU) / S
    keep = np.random.default_rng(seed).random(len(table)) < ndtr(z)
    ret_real = table.ret_real & (keep | ~table.ret_sim)
    i_real = np.where(ret_real, table.i_real, np.nan).astype(np.float32)
    return dataclasses.replace(table, ret_real=ret_real, i_real=i_real)


def fit_d1(table: BeamTable):
    design = paired_design(table)
    d1 = next(e for e in candidates(design) if e.info.id == "D1")
    rows = np.arange(len(design))
    model = Model([d1], float(design.ln_range.mean()), float(design.ln_sim.mean()))
    f = fit_best(model, design, np.ones(len(design)), initial_base(design, rows))
    return f, dict(zip(d1.names, f.effect_params("D1"), strict=True))


@pytest.mark.parametrize("on_measured", [False, True])
def test_a_detection_threshold_narrower_than_the_noise_is_fitted_inside_its_bounds(on_measured):
    # Object spread 0.25 and noise 0.1: the real value scatters by ~0.27 around the
    # prediction, more than S. A model that always censors y needs s^2 + 0.27^2 = S^2 on
    # a threshold of the predicted power: s ran to its lower bound and D1 was rejected.
    table = with_threshold(make_table(11, group_sd=0.25, noise=0.1), on_measured, seed=3)
    f, p = fit_d1(table)
    assert "D1" not in f.at_bound()
    assert p["ln_tau"] == pytest.approx(LN_TAU, abs=0.1)
    assert p["s"] == pytest.approx(S, abs=0.08)
    assert p["latent_share"] == pytest.approx(1.0 if on_measured else 0.0, abs=0.25)


def test_a_stored_zero_is_read_as_the_sub_step_power_its_geometry_predicts():
    # The simulation follows ln I = c - 2 ln R; its far beams fall below half a step and are
    # stored as 0. Their imputed power lies in the zero interval and falls with range.
    table = make_table(12, n_scans=4)
    h, step = table.sensor.half_step, table.sensor.step
    i_sim = np.where(table.ret_sim, np.round(2.0 / table.range_m.astype(float) ** 2, 2), np.nan)
    design = paired_design(dataclasses.replace(table, i_sim=i_sim.astype(np.float32)))
    zero = ~design.sim_ok.numpy()
    power = np.exp((design.ln_sim + design.sim_shift).numpy()[zero]) - h
    r = design.range_m.numpy()[zero]
    assert zero.sum() > 1000
    assert np.all((power >= 0.0) & (power <= 0.5 * step + 1e-12))
    assert np.corrcoef(np.log(r), power)[0, 1] < -0.8


def test_the_power_behind_values_stored_near_zero_is_imputed_without_bias():
    # A simulation whose law ln I = c - 2 ln R + N(0, 0.4) runs well below the first steps:
    # fitted on the values stored clear of them alone, the law sees only the far beams that
    # came out bright, and the stored 0s were imputed 0.16 too bright on average.
    table = make_table(13, n_scans=4)
    h, step = table.sensor.half_step, table.sensor.step
    rng = np.random.default_rng(13)
    r = table.range_m.astype(float)
    power = np.exp(np.log(4.0) - 2.0 * np.log(r) + rng.normal(0.0, 0.4, len(table)))
    i_sim = np.where(table.ret_sim, np.minimum(np.round(power / step) * step, 0.99), np.nan)
    design = paired_design(dataclasses.replace(table, i_sim=i_sim.astype(np.float32)))
    imputed = (design.ln_sim + design.sim_shift).numpy()
    truth = np.log(power[design.rows] + h)
    stored = i_sim[design.rows]
    for k in (0, 1, 2):
        rows = np.isclose(stored, k * step)
        assert rows.sum() > 500
        assert imputed[rows].mean() == pytest.approx(truth[rows].mean(), abs=0.06)
