"""The ground fit of `lads.physics.ground_fit` against labelled real frames: settings chosen
on validation frames, scored once on places and a sensor they never saw.

- validation: SemanticKITTI sequence 00, frames 000000-000002 (one place);
- test: SemanticKITTI 000052, 000088, 004501 (another place) and 000850 (380 m away),
  sequence 90 (another sequence), and the 40 nuScenes scene-0002 keyframes (HDL-32E).

Truth: the classes materials.yaml marks as level ground (road-like and terrain). Scores: IoU
of the fitted ground with the truth, the share of fitted ground that is road-like or
terrain (precision) and the share of the truth found (recall), pooled over each split's
points.

Run: .venv/bin/python -m benchmarks.ground_fit   (writes benchmarks/results/ground_fit.json)
"""

from __future__ import annotations

import itertools
from dataclasses import asdict
from typing import Any

import numpy as np
from tqdm import tqdm

from benchmarks.common import SHARED_DATA, machine_info, write_result
from lads.errors import InputDataError
from lads.physics.ground_fit import GroundFit, ground_mask
from lads.physics.materials import class_ids, class_roles
from lads.readers import get_reader

# (reader, folder under ../shared/data, label set, which relpaths belong to the split)
VALIDATION = (("semantickitti", "semantickitti", "semantickitti"),)
TEST = (
    ("semantickitti", "semantickitti-more", "semantickitti"),
    ("semantickitti", "semantickitti-seqx", "semantickitti"),
    ("nuscenes-kitti", "nuscenes-kittifmt", "nuscenes"),
)
GRID = {
    "cell_m": (1.0, 2.0, 3.0),
    "height_tol_m": (0.1, 0.15, 0.2, 0.3),
    "max_slope": (0.02, 0.05, 0.1),
}


def _frames(split: tuple[tuple[str, str, str], ...]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(xyz, truth) of every labelled frame of the split's trees."""
    out = []
    for reader_name, folder, label_set in split:
        root = SHARED_DATA / folder
        if not root.is_dir():
            raise InputDataError(f"real frames missing at {root} (../shared/data).")
        level = np.fromiter(class_roles(label_set).level_ground, dtype=np.int64)
        reader = get_reader(reader_name, root)
        for item in reader.items():
            frame = reader.read(item)
            if frame.labels is not None:
                truth = np.isin(class_ids(frame.labels, label_set), level)
                out.append((frame.xyz.copy(), truth))
    return out


def _scores(frames: list[tuple[np.ndarray, np.ndarray]], fit: GroundFit) -> dict[str, float]:
    hit = fitted = truth_n = 0
    for xyz, truth in frames:
        mask = ground_mask(xyz, fit)
        hit += int(np.count_nonzero(mask & truth))
        fitted += int(np.count_nonzero(mask))
        truth_n += int(np.count_nonzero(truth))
    union = fitted + truth_n - hit
    return {
        "iou": round(hit / union, 4) if union else 0.0,
        "precision": round(hit / fitted, 4) if fitted else 0.0,
        "recall": round(hit / truth_n, 4) if truth_n else 0.0,
        "frames": len(frames),
    }


def main() -> None:
    validation, test = _frames(VALIDATION), _frames(TEST)
    rows: list[dict[str, Any]] = []
    combos = list(itertools.product(*GRID.values()))
    for values in tqdm(combos, desc="ground fit grid", unit="setting"):
        fit = GroundFit(**dict(zip(GRID, values, strict=True)))
        rows.append({**asdict(fit), **_scores(validation, fit)})
    best = max(rows, key=lambda r: r["iou"])
    chosen = GroundFit(**{k: best[k] for k in GRID})
    payload = {
        "what": "ground fit vs level-ground labels; settings chosen on validation, test once",
        "validation_trees": [v[1] for v in VALIDATION],
        "test_trees": [t[1] for t in TEST],
        "chosen": asdict(chosen),
        "shipped_default": asdict(GroundFit()),
        "default_is_chosen": GroundFit() == chosen,
        "validation": _scores(validation, chosen),
        "test": _scores(test, chosen),
        "test_by_tree": {t[1]: _scores(_frames((t,)), chosen) for t in TEST},
        "grid": rows,
        "machine": machine_info(),
    }
    write_result("ground_fit.json", payload)


if __name__ == "__main__":
    main()
