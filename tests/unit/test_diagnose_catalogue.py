"""The effect catalogue is the one declaration of every effect: the fitter's candidates take
their parameters and bounds from it, and the report names what it declares."""

from __future__ import annotations

import numpy as np
import pytest

from lads.diagnose.effects import catalogue
from lads.diagnose.effects.base import catalogue_name
from lads.diagnose.effects.catalogue import CATALOGUE, FAMILIES, candidates
from lads.diagnose.fit.from_table import paired_design
from tests.unit.test_diagnose_localize import make_table


@pytest.fixture(scope="module")
def design():
    return paired_design(make_table(0))


def test_every_fitted_parameter_is_catalogued_and_bounded_as_declared(design):
    offered = set()
    for effect in candidates(design):
        info = CATALOGUE[effect.info.id]
        offered.add(info.id)
        for name, low, high in zip(effect.names, effect.lower, effect.upper, strict=True):
            assert catalogue_name(name) in info.params, (effect.label, name, info.params)
            assert (float(low), float(high)) == info.bound(name, design.max_value)
            assert low < high
    # A paired, labelled design is offered every family but the class-confined ones its
    # classes lack (no retro-reflective class here), and nothing the catalogue says has no
    # term yet.
    assert offered <= {i for i, e in CATALOGUE.items() if e.offered}
    assert {i for i, e in CATALOGUE.items() if e.offered} - offered == {"C3r"}


def test_report_parameters_are_the_catalogue_names(design):
    for effect in candidates(design):
        theta = np.array([s for s in effect.starts[0]], dtype=np.float64)
        exported = effect.export(theta)
        info = effect.info
        extra = {"rings"}  # per-ring effects also name the rings they act on
        for name in exported:
            assert catalogue_name(name) in set(info.params) | extra, (effect.label, name)


def test_encoded_bounds_scale_with_a_float_encoding():
    info = CATALOGUE["C4o"]
    assert info.bound("offset_by_ring[3]", 255.0) == (-20.0, 20.0)
    low, high = info.bound("offset_by_ring[3]", 1.0)
    assert high == pytest.approx(20.0 / 255.0) and low == -high
    assert CATALOGUE["C1"].bound("delta_n", 1.0) == (-2.5, 2.0)  # not encoded: unscaled


def test_ids_and_keys_are_unique_and_every_family_is_documented():
    infos = [info for m in FAMILIES for info in m.INFOS]
    assert len({i.id for i in infos}) == len(infos) == len(CATALOGUE)
    assert len({i.key for i in infos}) == len(infos)
    for info in infos:
        assert f"{info.id} " in catalogue.__doc__ and info.key in catalogue.__doc__
        assert set(info.confounds) <= set(CATALOGUE), info.id
        assert len(info.bounds) == len(info.params)
    # A family module is named after its first entry, so a reader finds C5 by file name.
    for module in FAMILIES:
        stem = module.__name__.rsplit(".", 1)[1]
        assert stem.split("_", 1)[0] == module.INFOS[0].id.lower(), stem


def test_a_parameter_without_a_numeric_bound_cannot_be_fitted():
    with pytest.raises(KeyError):
        CATALOGUE["C9"].bound("i_max")
    with pytest.raises(KeyError):
        CATALOGUE["C1"].bound("no_such_parameter")
