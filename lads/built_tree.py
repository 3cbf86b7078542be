"""What a built tree is: its plan, its identity, the names of its files and its state folder.

A leaf of the build path (worker <- finalise <- runner, and verify) that every one of them
reads, so a file name or the rule that recovers a finished tree's plan is defined once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from lads.config import PipelineConfig, parse_pipeline
from lads.errors import ManifestError
from lads.files import sha256_bytes
from lads.lock import LOCK_NAME

MANIFEST = "manifest.jsonl"
RUN_JSON = "run.json"
PIPELINE_YAML = "pipeline.yaml"
SHA256SUMS = "SHA256SUMS"
RUN_REPORT = "run_report.json"
PREVIEW = "figures/preview.png"
# Files of the tree that SHA256SUMS does not list (itself, the run's timings, the lock).
NOT_SUMMED = frozenset({SHA256SUMS, RUN_REPORT, LOCK_NAME})
# The journal of a build under way (finished items, the plan); removed when it finishes.
STATE_DIR = ".lads-state"
PLAN_JSON = "plan.json"


@dataclass(frozen=True, slots=True)
class BuildPlan:
    """Everything a worker needs to process items; picklable, no open handles.

    Attributes:
        source: reader name.
        source_root, out_root: absolute paths as strings.
        reader_options: (key, value) pairs passed to the reader constructor.
        pipeline: the effective pipeline.
        seed: root seed of the run.
    """

    source: str
    source_root: str
    out_root: str
    reader_options: tuple[tuple[str, Any], ...]
    pipeline: PipelineConfig
    seed: int


def identity(plan: BuildPlan) -> dict[str, Any]:
    """What makes two builds the same build (run.json and the state folder's plan.json)."""
    return {
        "source": plan.source,
        "seed": plan.seed,
        "reader_options": {
            k: list(v) if isinstance(v, tuple) else v for k, v in plan.reader_options
        },
        "config_hash": plan.pipeline.config_hash(),
    }


def freeze_options(options: dict[str, Any]) -> tuple[tuple[str, Any], ...]:
    """Reader options as sorted (key, value) pairs, lists as tuples (hashable, picklable)."""
    return tuple(
        (k, tuple(v) if isinstance(v, list | tuple) else v) for k, v in sorted(options.items())
    )


def trial_subset(run: Any) -> tuple[int, int] | None:
    """(items the tree holds, items of its source) of a tree whose run.json says a --limit
    build left source items out; None for any other tree or record."""
    if not isinstance(run, dict) or not isinstance(run.get("limit"), int):
        return None
    items, total = run.get("items"), run.get("source_items")
    if isinstance(items, int) and isinstance(total, int) and items < total:
        return items, total
    return None


def state_path(out_root: Path, item_id: str) -> Path:
    """Where the finished-item record of one item is journaled during a build."""
    return out_root / STATE_DIR / "items" / (sha256_bytes(item_id.encode())[:32] + ".json")


def plan_from_tree(out_root: Path, source_root: Path) -> BuildPlan:
    """The BuildPlan a finished tree was built with (from its run.json and pipeline.yaml)."""
    out_root, source_root = Path(out_root).resolve(), Path(source_root).resolve()
    try:
        run = json.loads((out_root / RUN_JSON).read_text())
        data = yaml.safe_load((out_root / PIPELINE_YAML).read_text())
    except (OSError, json.JSONDecodeError, yaml.YAMLError) as exc:
        raise ManifestError(
            f"{out_root}: cannot read {RUN_JSON} / {PIPELINE_YAML} ({exc}); is this a finished "
            "lads build?"
        ) from exc
    pipeline = parse_pipeline(data, str(out_root / PIPELINE_YAML))
    if pipeline.config_hash() != run.get("config_hash"):
        raise ManifestError(
            f"{out_root / PIPELINE_YAML}: its hash does not match run.json config_hash; the tree "
            "was edited after the build."
        )
    options = freeze_options(run.get("reader_options", {}))
    return BuildPlan(
        run["source"], str(source_root), str(out_root), options, pipeline, int(run["seed"])
    )
