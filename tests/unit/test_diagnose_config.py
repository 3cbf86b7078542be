"""One source of truth for diagnose thresholds: config.py, read by the modules, saved in reports."""

from __future__ import annotations

import dataclasses
import json

import pytest

from lads.diagnose.config import CONFIG, TUNED_ON, DiagnoseConfig
from lads.diagnose.data import beams
from lads.diagnose.fit import from_table, model
from lads.diagnose.selection import select
from lads.diagnose.verdict import ambiguity


def test_the_modules_read_their_thresholds_from_the_config():
    assert select.Z_ACCEPT is CONFIG.select.z_accept
    assert model.MAXCOR is CONFIG.fit.maxcor
    assert from_table.TOBIT_MAX_ROWS is CONFIG.design.tobit_max_rows
    assert beams.GROUND_INLIER_M is CONFIG.table.ground_inlier_m
    assert ambiguity.LONG_RANGE_BAND_M is CONFIG.verdict.long_range_band_m


def test_the_config_is_json_and_its_hash_follows_every_value():
    text = json.dumps(CONFIG.to_dict(), allow_nan=False)  # an infinite bin edge is "inf"
    assert '"inf"' in text
    changed = dataclasses.replace(CONFIG, select=dataclasses.replace(CONFIG.select, z_accept=3.5))
    assert changed.sha256() != CONFIG.sha256() == DiagnoseConfig().sha256()
    with pytest.raises(dataclasses.FrozenInstanceError):
        CONFIG.select.z_accept = 2.0  # type: ignore[misc]


def test_every_tuned_value_names_an_existing_field():
    for path in TUNED_ON:
        group, name = path.split(".")
        assert hasattr(getattr(CONFIG, group), name), path
