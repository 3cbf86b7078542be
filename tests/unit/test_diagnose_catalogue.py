"""The effect catalogue states the parameters and bounds the fitter really uses."""

from __future__ import annotations

import re

import numpy as np

from lads.diagnose.effects.catalogue import CATALOGUE
from lads.diagnose.effects.terms import candidates
from lads.diagnose.fit.design import paired_design
from tests.unit.test_diagnose_localize import make_table

# Bounds set from the data, not the catalogue: offsets in the frame's encoding units.
SCALED = {("C4o", "offset_by_ring"), ("C9", "offset")}


def _catalogue_name(name: str) -> str:
    """A fitted parameter's catalogue name: ring vectors and per-class names collapse."""
    name = re.sub(r"\[\d+\]$", "", name)
    for prefix in ("ln_scale_", "wet_share_"):
        if name.startswith(prefix):
            return prefix + "<class>"
    return name


def test_every_fitted_parameter_is_catalogued_with_the_bounds_it_is_fitted_in():
    design = paired_design(make_table(0))
    checked = set()
    for effect in candidates(design):
        info = CATALOGUE[effect.info.id]
        for name, low, high in zip(effect.names, effect.lower, effect.upper, strict=True):
            key = _catalogue_name(name)
            assert key in info.params, (effect.label, name, info.params)
            if (info.id, key) in SCALED:
                continue
            want = info.bounds[info.params.index(key)]
            got = (None if not np.isfinite(low) else float(low),
                   None if not np.isfinite(high) else float(high))  # fmt: skip
            assert got == want, (effect.label, name, got, want)
            checked.add(info.id)
    # The drift this test was written for: wet surface, blockage and detection threshold.
    assert {"C7", "C11", "D1"} <= checked
