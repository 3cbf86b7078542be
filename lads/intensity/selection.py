"""Choosing a model on the validation frames, and only there.

During training, every checkpoint's generator is scored on each pair's validation split
(`lads.intensity.splits`): paired MAE plus the cell-conditional Wasserstein-1 (class x range
x incidence), both in reflectivity units, averaged over pairs: the two things the shipped
weights must do well. The best-scoring checkpoint is kept as `RUN/best.pt` with its scores in
`RUN/selection.json`, both rewritten atomically, so a resumed run keeps choosing where it
left off; the weight file the run writes is that checkpoint. Test frames are never read
here. A config without validation frames keeps the last step (and says so).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lads.files import atomic_write
from lads.intensity.checkpoint import IntensityModel, ModelMeta, save_model
from lads.intensity.model import Generator, PointGenerator
from lads.intensity.train_config import TrainConfig

BEST = "best.pt"
SELECTION = "selection.json"
CRITERION = ("mae_reflectivity", "cell_w1_reflectivity")


def validation_frames(cfg: TrainConfig) -> dict[str, list[Any]]:
    """{pair key: EvalFrames of its target's validation split} (empty lists allowed)."""
    from lads.intensity.cache import role_split
    from lads.intensity.eval_frames import frames_of

    return {
        p.key: frames_of(role_split(p.target, "validation", f"pairs.{p.key}.target"), cfg.kind)
        for p in cfg.pairs
    }


def score(model: IntensityModel, frames: dict[str, list[Any]]) -> dict[str, Any]:
    """Validation metrics of `model`: per pair the CRITERION metrics, and "score", their sum
    averaged over the pairs that have validation frames (None without any)."""
    from lads.intensity.evaluate import evaluate
    from lads.intensity.predict import predict_points

    per_pair: dict[str, dict[str, float]] = {}
    for key, heldout in frames.items():
        if not heldout:
            continue

        def generator(frame: Any, key: str = key) -> Any:
            return predict_points(
                model,
                frame.xyz,
                frame.profile,
                target=key,
                labels=frame.labels,
                label_set=frame.label_set,
                ring=frame.ring,
                particle=frame.particle,
                extinction_per_m=frame.extinction_per_m,
                where=frame.name,
            ).encoded

        pooled = evaluate(heldout, {"generator": generator}).pooled["generator"]
        per_pair[key] = {m: float(pooled[m]) for m in CRITERION}
    if not per_pair:
        return {"pairs": {}, "score": None}
    total = sum(sum(v.values()) for v in per_pair.values()) / len(per_pair)
    return {"pairs": per_pair, "score": total}


class Selector:
    """The best checkpoint so far, kept on disk in the run folder."""

    def __init__(self, run: Path, config_id: str, *, resumed: bool) -> None:
        """`config_id` names the training config; the stored choice is carried on only by
        a run resumed from its checkpoint under the same config. A run that starts at
        step 0 chooses afresh: a best checkpoint left by an earlier run (another config, or
        the same one before its checkpoint was deleted) must not win over the new run."""
        self.run = run
        path = run / SELECTION
        stored = json.loads(path.read_text()) if resumed and path.is_file() else None
        if stored is None or stored.get("config", config_id) != config_id:
            stored = {"history": [], "best": None}
        stored["config"] = config_id
        self.record: dict[str, Any] = stored

    def offer(
        self, step: int, meta: ModelMeta, generator: Generator | PointGenerator, scores: dict
    ) -> bool:
        """Record `scores` of the checkpoint at `step`; keep it when it is the best."""
        self.record["history"].append({"step": step, **scores})
        best = self.record["best"]
        better = scores["score"] is not None and (best is None or scores["score"] < best["score"])
        if better:
            save_model(self.run / BEST, meta, generator)
            self.record["best"] = {"step": step, **scores}
        atomic_write(self.run / SELECTION, json.dumps(self.record, indent=1).encode())
        return better

    @property
    def best_step(self) -> int | None:
        best = self.record["best"]
        return None if best is None else int(best["step"])
