"""Model cards read the same whether scored now or rendered from eval.json."""

from __future__ import annotations

import dataclasses

from lads.intensity.model_card import _held_line, _metrics_table
from lads.intensity.train_config import parse_train_config


def _result(methods: list[str]) -> dict:
    pooled = {m: {"mae_reflectivity": len(m) / 100} for m in methods}
    beats = {"mae_reflectivity": {m: True for m in methods if m != "generator"}}
    return {
        "context": {"frames": ["a.bin"], "split": "test"},
        "pooled": pooled,
        "summary": {"beats": beats},
    }


def test_the_metrics_table_is_sorted_whatever_the_order_it_is_given():
    order = ["unchanged", "per_class_median", "generator", "fitted_physics"]
    one = _metrics_table({"snow": _result(order), "fog": _result(order)})
    two = _metrics_table({"fog": _result(order[::-1]), "snow": _result(order[::-1])})
    rows = [line.split(" | ")[0] for line in one if line.startswith("| ") and "---" not in line]
    assert [r for r in rows if r != "| method"][:4] == [
        "| fitted_physics",
        "| generator",
        "| per_class_median",
        "| unchanged",
    ]
    assert one[0].startswith("### fog") and one == two


def test_the_card_names_the_materials_held_at_the_unseen_vector():
    raw = {
        "schema_version": 1,
        "name": "tiny",
        "kind": "sensor",
        "pairs": {
            "kitti": {
                "source": {"dataset": "synth", "sensor": "hdl64e", "frames": 1},
                "target": {"dataset": "semantickitti", "root": "/nonexistent"},
            }
        },
    }
    cfg = dataclasses.replace(parse_train_config(raw, "t"), material_min_points=1000)
    assert _held_line(cfg, []) == []
    (line,) = _held_line(cfg, ["glass", "wood"])
    assert "fewer than 1000" in line and line.endswith("glass, wood")
