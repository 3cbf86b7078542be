"""Held-out evaluation of the shipped intensity generators -> intensity_eval.json.

For every shipped config with held-out frames: `lads eval-intensity` (generator against
unchanged, physics rescaled, global and per-class histogram matching), figures under
benchmarks/results/intensity/<config>/<pair>/.
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
            beats = res.get("summary", {}).get("beats", {})
            sys.stdout.write(f"intensity eval {key}: beats {beats}\n")
    results["machine"] = machine_info()
    path = write_result("intensity_eval.json", results)
    sys.stdout.write(f"intensity eval -> {path}\n")
    return results


if __name__ == "__main__":
    main()
