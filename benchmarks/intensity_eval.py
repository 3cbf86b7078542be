"""Held-out evaluation of the shipped intensity generators -> intensity_eval.json.

For every shipped config with a test split: `lads eval-intensity` on the test frames
(generator against every baseline of `lads.intensity.baselines`, fitted on the train split,
and the targets of `lads.intensity.targets`), figures under
benchmarks/results/intensity/<config>/<pair>/. Run it once per shipped model: the test
frames choose nothing.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from benchmarks.common import SHARED_DATA, machine_info, write_result
from lads.intensity.cache import role_split
from lads.intensity.commands import evaluate_pair
from lads.intensity.train_config import load_train_config

CONFIGS = ("synth-to-kitti", "synth-to-nuscenes", "weather")
FIGURES = Path(__file__).resolve().parent / "results" / "intensity"


def main() -> dict[str, Any]:
    results: dict[str, Any] = {}
    for name in CONFIGS:
        cfg = load_train_config(name, data_root=SHARED_DATA)
        for pair in cfg.pairs:
            key = f"{name}/{pair.key}"
            if not role_split(pair.target, "test", key):
                results[key] = {"skipped": "no test split (see the model card)"}
                continue
            res = evaluate_pair(cfg, pair, name, FIGURES / name)  # the shipped weights
            results[key] = res
            rows = res.get("summary", {}).get("targets", [])
            met = [r["target"] for r in rows if r["met"]]
            missed = [r["target"] for r in rows if not r["met"]]
            sys.stdout.write(f"intensity eval {key}: targets met {met}, missed {missed}\n")
    results["machine"] = machine_info()
    path = write_result("intensity_eval.json", results)
    sys.stdout.write(f"intensity eval -> {path}\n")
    return results


if __name__ == "__main__":
    main()
