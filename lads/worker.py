"""One item, start to finish: read -> stages -> correspondence -> encode -> write -> hash.

`process_item` is a top-level function of picklable arguments so joblib (loky) and Dask can
ship it to workers. Readers and stages are built once per worker process and cached.
"""

from __future__ import annotations

import functools
import json
import resource
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lads import correspondence, provenance
from lads.config import PipelineConfig
from lads.errors import LadsError, OutputWriteError
from lads.files import atomic_write, sha256_bytes, sha256_file, write_error
from lads.frame import Frame, Item
from lads.readers import get_reader
from lads.readers.base import EncodedFile, Reader
from lads.seeding import rng_for, seed_entropy
from lads.stages import build_stage
from lads.stages.base import Stage

STATE_DIR = ".lads-state"


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


@functools.lru_cache(maxsize=4)
def _reader(source: str, root: str, options: tuple[tuple[str, Any], ...]) -> Reader:
    return get_reader(source, Path(root), **dict(options))


_STAGE_CACHE: dict[str, tuple[Stage, ...]] = {}


def stages_for(pipeline: PipelineConfig) -> tuple[Stage, ...]:
    key = pipeline.config_hash()
    if key not in _STAGE_CACHE:
        _STAGE_CACHE[key] = tuple(build_stage(s) for s in pipeline.stages)
    return _STAGE_CACHE[key]


def reader_for(plan: BuildPlan) -> Reader:
    return _reader(plan.source, plan.source_root, plan.reader_options)


def transform(item: Item, plan: BuildPlan) -> tuple[Frame, list[EncodedFile], dict[str, Any], Any]:
    """Compute one item's output in memory (no writes).

    Returns:
        (frame to encode, encoded files, manifest fields without outputs, (source_index,
        outcome, n_source) for provenance).
    """
    reader = reader_for(plan)
    source = reader.read(item)
    frame = source
    stage_rows = []
    for spec, stage in zip(plan.pipeline.stages, stages_for(plan.pipeline), strict=True):
        entropy = seed_entropy(plan.seed, item.item_id, plan.pipeline.variant, stage.name)
        frame = stage(frame, rng_for(plan.seed, item.item_id, plan.pipeline.variant, stage.name))
        stage_rows.append(
            {"name": stage.name, "version": stage.version, "params_hash": spec.params_hash(),
             "seed_entropy": entropy}
        )  # fmt: skip
    if plan.pipeline.points == "aligned":
        encoded_frame, source_index, outcome = correspondence.aligned(source, frame)
    else:
        label = (
            reader.particle_label
            if plan.pipeline.particle_label is None
            else plan.pipeline.particle_label
        )
        encoded_frame, source_index, outcome = correspondence.physical(frame, label)
    files = reader.encode(encoded_frame)
    fields = {
        "item_id": item.item_id,
        "points": correspondence.outcome_counts(source.n_source, outcome, frame.lost_index.size),
        "stages": stage_rows,
    }
    return encoded_frame, files, fields, (source_index, outcome, source.n_source)


def _source_rows(item: Item, root: Path) -> list[dict[str, Any]]:
    rows = []
    for rel in item.source_relpaths():
        path = root / rel
        rows.append({"path": rel, "bytes": path.stat().st_size, "sha256": sha256_file(path)})
    return rows


def _output_rows(files: list[EncodedFile]) -> list[dict[str, Any]]:
    return [
        {"path": f.relpath, "role": f.role, "bytes": len(f.payload),
         "sha256": sha256_bytes(f.payload), "records": f.records, "record_bytes": f.record_bytes}
        for f in files
    ]  # fmt: skip


def state_path(out_root: Path, item_id: str) -> Path:
    """Where the finished-item record of one item is journaled during a build."""
    return out_root / STATE_DIR / "items" / (sha256_bytes(item_id.encode())[:32] + ".json")


def process_item(item: Item, plan: BuildPlan) -> dict[str, Any]:
    """Build one item and return its manifest row; never raises for a bad item.

    The outputs and provenance are written first, the journal record last, so a record
    exists only for an item whose files are complete (a killed run redoes the rest).
    A LadsError (bad input) or any other exception becomes a row with status "failed",
    except an OutputWriteError (disk full, read-only output): it stops the whole build,
    since every later item would fail the same way.
    """
    start = time.perf_counter()
    out_root = Path(plan.out_root)
    try:
        _, files, fields, (source_index, outcome, n_source) = transform(item, plan)
        row: dict[str, Any] = {
            **fields,
            "status": "ok",
            "source": _source_rows(item, reader_for(plan).root),
            "outputs": _output_rows(files),
        }
        for f in files:
            atomic_write(out_root / f.relpath, f.payload)
        _write_provenance(out_root, item, source_index, outcome, n_source)
    except OutputWriteError:
        raise
    except LadsError as exc:
        row = _failed(item, f"{type(exc).__name__}: {exc}")
    except Exception as exc:  # noqa: BLE001 - one bad frame must not end a 23k-frame build
        row = _failed(item, f"internal error {type(exc).__name__}: {exc} (please report this)")
    atomic_write(state_path(out_root, item.item_id), json.dumps(row, sort_keys=True).encode())
    row["_seconds"] = time.perf_counter() - start
    # ru_maxrss is in KiB on Linux: the worker's peak resident memory so far.
    row["_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return row


def _write_provenance(out_root: Path, item: Item, source_index: Any, outcome: Any, n: int) -> None:
    """provenance.write_item, with a write failure of the store said in words."""
    try:
        provenance.write_item(out_root, item.relpath, item.item_id, source_index, outcome, n)
    except OSError as exc:
        raise write_error(out_root / provenance.STORE_NAME, exc) from exc


def _failed(item: Item, message: str) -> dict[str, Any]:
    return {
        "item_id": item.item_id,
        "status": "failed",
        "error": message,
        "source": [],
        "outputs": [],
    }


def regenerate_outputs(
    out_root: Path, source_root: Path, item_ids: list[str]
) -> dict[str, dict[str, str]]:
    """Recompute some items of a built tree in memory: item_id -> {relpath: sha256}.

    Uses the tree's own OUT/pipeline.yaml and run.json, so the bytes must match the
    manifest if the build was deterministic and neither tree changed.
    """
    from lads.runner import plan_from_tree

    plan = plan_from_tree(out_root, source_root)
    wanted = set(item_ids)
    items = [i for i in reader_for(plan).items() if i.item_id in wanted]
    result: dict[str, dict[str, str]] = {}
    for item in items:
        _, files, _, _ = transform(item, plan)
        result[item.item_id] = {f.relpath: sha256_bytes(f.payload) for f in files}
    return result
