"""Encoding effects (C9): a power law and offset fitted on the log scale, and a clip below
the encoding's maximum read off the data and censored (lads/diagnose/{effects,design}.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lads.diagnose.data.table import BeamTable
from lads.diagnose.effects.catalogue import candidates
from lads.diagnose.fit.from_table import clip_level, paired_design
from lads.diagnose.fit.likelihood import Model
from lads.diagnose.fit.model import fit_best, initial_base
from tests.unit.test_diagnose_localize import make_table

GAMMA, OFFSET, I_MAX, NOISE = 0.7, 0.02, 0.6, 0.35


def encoded(seed: int, i_max: float | None = I_MAX) -> BeamTable:
    """Simulated KITTI values from 0.01 to 0.9 (log-uniform); reality measures them with
    log-normal noise, then maps I -> I^GAMMA + OFFSET, clips at i_max, rounds to 0.01."""
    table = make_table(seed, noise=0.0)
    rng = np.random.default_rng(seed + 100)
    h = table.sensor.half_step
    n = len(table)
    i_sim = np.round(np.exp(rng.uniform(np.log(0.01), np.log(0.9), n)), 2)
    measured = (i_sim + h) * np.exp(rng.normal(0.0, NOISE, n)) - h
    out = np.maximum(measured, 0.0) ** GAMMA + OFFSET
    if i_max is not None:
        out = np.minimum(out, i_max)
    i_real = np.clip(np.round(out, 2), 0.0, 0.99)
    ret_real = table.ret_real & table.ret_sim
    return dataclasses.replace(
        table,
        ret_real=ret_real,
        i_sim=np.where(table.ret_sim, i_sim, np.nan).astype(np.float32),
        i_real=np.where(ret_real, i_real, np.nan).astype(np.float32),
    )


def fit_c9(table: BeamTable):
    design = paired_design(table)
    c9 = next(e for e in candidates(design) if e.info.id == "C9")
    model = Model([c9], float(design.ln_range.mean()), float(design.ln_sim.mean()))
    rows = np.arange(len(design))
    f = fit_best(model, design, np.ones(len(design)), initial_base(design, rows))
    return design, c9, f


def test_a_power_law_offset_and_clip_on_the_noisy_value_are_recovered():
    # A tenth of the values sit at the clip; read as exact values they flatten the top of
    # the map and pull gamma low.
    design, c9, f = fit_c9(encoded(21))
    params = c9.export(f.effect_params("C9"))
    assert params["gamma"] == pytest.approx(GAMMA, abs=0.04)
    assert params["offset"] == pytest.approx(OFFSET, abs=0.005)
    assert params["i_max"] == pytest.approx(I_MAX, abs=1e-6)


def test_values_at_a_clip_below_the_maximum_are_censored_from_below():
    design = paired_design(encoded(22))
    at_clip = design.returned.numpy() & (np.abs(np.exp(design.y.numpy()) - 0.005 - I_MAX) < 1e-4)
    assert design.real_clip == pytest.approx(I_MAX, abs=1e-6)
    assert at_clip.sum() > 100
    assert (design.censor.numpy()[at_clip] == 3).all()


def test_without_a_clip_none_is_found_and_only_the_encodings_maximum_is_censored():
    design = paired_design(encoded(23, i_max=None))
    assert design.real_clip is None
    above = design.censor.numpy() == 3
    assert np.allclose(np.exp(design.y.numpy()[above]) - 0.005, 0.99, atol=1e-4)
    c9 = next(e for e in candidates(design) if e.info.id == "C9")
    assert "i_max" not in c9.export(np.array([1.0, 0.0]))


def test_clip_level_needs_an_atom_at_the_top_not_a_thinning_tail():
    rng = np.random.default_rng(0)
    tail = np.round(np.exp(rng.normal(np.log(0.1), 0.6, 20000)), 2)
    tail = tail[tail < 0.99]
    assert clip_level(tail, 0.01, 0.99) is None
    assert clip_level(np.minimum(tail, 0.3), 0.01, 0.99) == pytest.approx(0.3)
    # Saturation at the encoding's own maximum is the encoding's, already censored.
    assert clip_level(np.minimum(tail, 0.99), 0.01, 0.99) is None
