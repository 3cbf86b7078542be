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
from lads.built_tree import BuildPlan, plan_from_tree, state_path
from lads.config import PipelineConfig
from lads.errors import LadsError, OutputWriteError
from lads.files import atomic_write, sha256_bytes, sha256_file, write_error
from lads.frame import Frame, Item
from lads.jsontypes import json_types
from lads.readers import get_reader, with_columns
from lads.readers.base import EncodedFile, Reader
from lads.seeding import rng_for, seed_entropy
from lads.stages import build_stages
from lads.stages.base import Stage
from lads.windows import run_track_stage, run_window_stage, window_source_rows


@functools.lru_cache(maxsize=4)
def _reader(source: str, root: str, options: tuple[tuple[str, Any], ...]) -> Reader:
    return get_reader(source, Path(root), **dict(options))


_STAGE_CACHE: dict[str, tuple[Stage, ...]] = {}


def stages_for(pipeline: PipelineConfig) -> tuple[Stage, ...]:
    key = pipeline.config_hash()
    if key not in _STAGE_CACHE:
        _STAGE_CACHE[key] = build_stages(pipeline)
    return _STAGE_CACHE[key]


def reader_for(plan: BuildPlan) -> Reader:
    return _reader(plan.source, plan.source_root, plan.reader_options)


@functools.lru_cache(maxsize=4)
def _writer(
    source: str, root: str, options: tuple[tuple[str, Any], ...], columns: tuple[str, ...]
) -> Reader:
    return with_columns(_reader(source, root, options), columns)


def writer_for(plan: BuildPlan) -> Reader:
    """The reader that encodes the build's outputs: the source's, in the point record the
    pipeline writes (the source's own, or the target's native one: `point_record`)."""
    record = plan.pipeline.point_record()
    if record is None:
        return reader_for(plan)
    return _writer(plan.source, plan.source_root, plan.reader_options, record.columns)


class _Clock:
    """Adds the milliseconds since the previous lap to `timings[name]` (None: no timing)."""

    def __init__(self, timings: dict[str, float] | None) -> None:
        self.timings = timings
        self.last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        if self.timings is not None:
            self.timings[name] = self.timings.get(name, 0.0) + (now - self.last) * 1e3
        self.last = now


@dataclass(frozen=True, slots=True)
class Partial:
    """An item already read and run through its first `next_stage` stages (batched path)."""

    source: Frame
    frame: Frame
    next_stage: int


def _rng(plan: BuildPlan, item: Item, stage: Stage) -> Any:
    return rng_for(plan.seed, item.item_id, plan.pipeline.variant, stage.name)


def _run_stages(
    item: Item, plan: BuildPlan, frame: Frame, stages: tuple[Stage, ...], clock: _Clock
) -> Frame:
    """`frame` through `stages` in order, each with its own rng; one lap per stage. A stage
    that transfers from a window (the sensor stage) gets the window read here, and one that
    needs the frame's poses (motion from poses) its reader's pose track."""
    for stage in stages:
        if hasattr(stage, "call_window"):
            key = f"{plan.pipeline.config_hash()}:{stage.name}"
            frame = run_window_stage(
                stage,  # type: ignore[arg-type]
                key,
                reader_for(plan),
                item,
                frame,
                _rng(plan, item, stage),
            )
        elif getattr(stage, "needs_track", False):
            frame = run_track_stage(stage, reader_for(plan), item, frame, _rng(plan, item, stage))
        else:
            frame = stage(frame, _rng(plan, item, stage))
        clock.lap(f"stage:{stage.name}")
    return frame


def transform(
    item: Item,
    plan: BuildPlan,
    timings: dict[str, float] | None = None,
    partial: Partial | None = None,
) -> tuple[Frame, list[EncodedFile], dict[str, Any], Any]:
    """Compute one item's output in memory (no writes).

    `timings`, when given, receives milliseconds per step: read, stage:NAME, encode
    (correspondence included). `partial` continues an item the batched path has taken
    through its first stages.

    Returns:
        (frame to encode, encoded files, manifest fields without outputs, (source_index,
        outcome, n_source) for provenance).
    """
    reader = reader_for(plan)
    clock = _Clock(timings)
    if partial is None:
        source = reader.read(item)
        frame, first = source, 0
        clock.lap("read")
    else:
        source, frame, first = partial.source, partial.frame, partial.next_stage
    stages = stages_for(plan.pipeline)
    frame = _run_stages(item, plan, frame, stages[first:], clock)
    stage_rows = []
    for spec, stage in zip(plan.pipeline.stages, stages, strict=True):
        entropy = seed_entropy(plan.seed, item.item_id, plan.pipeline.variant, stage.name)
        stage_rows.append(
            {
                "name": stage.name,
                "version": stage.version,
                "params_hash": spec.params_hash(),
                "seed_entropy": entropy,
            }
        )
    if plan.pipeline.points == "resampled":
        encoded_frame, source_index, outcome = frame, frame.source_index, frame.outcome
    elif plan.pipeline.points == "aligned":
        encoded_frame, source_index, outcome = correspondence.aligned(source, frame)
    else:
        label = (
            reader.particle_label
            if plan.pipeline.particle_label is None
            else plan.pipeline.particle_label
        )
        encoded_frame, source_index, outcome = correspondence.physical(frame, label)
    files = writer_for(plan).encode(encoded_frame)
    clock.lap("encode")
    fields = {
        "item_id": item.item_id,
        "points": correspondence.outcome_counts(
            source.n_source, outcome, frame.lost_index.size, source_index
        ),
        "stages": stage_rows,
        "conditions": _conditions(frame),
    }
    return encoded_frame, files, fields, (source_index, outcome, source.n_source)


def _conditions(frame: Frame) -> dict[str, Any]:
    """What the stages did to the whole frame (`Frame.conditions`, the last value of a key
    wins), in JSON types (`lads.jsontypes`)."""
    return json_types(dict(frame.conditions))  # type: ignore[no-any-return]


def _tracked(plan: BuildPlan) -> bool:
    """Whether a stage of the build takes the vehicle's motion from the reader's poses."""
    return any(getattr(s, "needs_track", False) for s in stages_for(plan.pipeline))


def _source_rows(item: Item, root: Path) -> list[dict[str, Any]]:
    rows = []
    for rel in item.source_relpaths():
        path = root / rel
        rows.append({"path": rel, "bytes": path.stat().st_size, "sha256": sha256_file(path)})
    return rows


def _output_rows(files: list[EncodedFile]) -> list[dict[str, Any]]:
    return [
        {
            "path": f.relpath,
            "role": f.role,
            "bytes": len(f.payload),
            "sha256": sha256_bytes(f.payload),
            "records": f.records,
            "record_bytes": f.record_bytes,
        }
        for f in files
    ]


# glibc's own ceiling for its adaptive mmap threshold on 64-bit Linux (4 MiB x sizeof(long)).
MMAP_THRESHOLD_BYTES = 32 << 20


@functools.lru_cache(maxsize=1)
def tune_allocator() -> bool:
    """Give a worker started with glibc malloc tuning in its environment (Dask's nanny sets
    MALLOC_TRIM_THRESHOLD_) the heap reuse glibc would otherwise adapt to by itself.

    Setting any such variable switches off glibc's adaptive mmap threshold: every array over
    128 kB was then mapped fresh and page-faulted in, and a Dask worker spent most of its
    time in the kernel (3x slower per frame than a loky worker). Here the thresholds are set
    to where glibc's adaptation ends (mmap 32 MiB, trim twice that). Workers without such a
    variable (loky, --jobs) are left alone. Returns whether a setting was made.
    """
    import ctypes
    import ctypes.util
    import os
    import sys

    tuned = any(k.startswith("MALLOC_") and k.endswith("_") for k in os.environ)
    if not (tuned and sys.platform.startswith("linux")):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3  # mallopt parameters, <malloc.h>
        ok = libc.mallopt(m_mmap_threshold, MMAP_THRESHOLD_BYTES) == 1
        return ok and libc.mallopt(m_trim_threshold, 2 * MMAP_THRESHOLD_BYTES) == 1
    except (OSError, AttributeError):
        return False


def process_items(items: list[Item], plan: BuildPlan) -> list[dict[str, Any]]:
    """`process_item` for a batch: a stage with `call_batch` (the learned intensity stage)
    runs once for all the items (many frames per forward pass on a GPU); the other steps
    run item by item. Every item gets the files and row it gets alone: an item that fails
    before the batched stage, or a batch whose stage call fails, is redone item by item,
    so a bad frame fails alone."""
    tune_allocator()
    stages = stages_for(plan.pipeline)
    first = next((k for k, s in enumerate(stages) if hasattr(s, "call_batch")), None)
    if first is None or len(items) < 2:
        return [process_item(item, plan) for item in items]
    timings: dict[str, dict[str, float]] = {i.item_id: {} for i in items}
    ready: dict[str, tuple[Frame, Frame]] = {}
    for item in items:
        clock = _Clock(timings[item.item_id])
        try:
            source = reader_for(plan).read(item)
            clock.lap("read")
            frame = _run_stages(item, plan, source, stages[:first], clock)
        except Exception:  # noqa: BLE001 - redone alone below, where its error is recorded
            continue
        ready[item.item_id] = (source, frame)
    batch = [i for i in items if i.item_id in ready]
    partials: dict[str, Partial] = {}
    start = time.perf_counter()
    try:
        stage = stages[first]
        frames = stage.call_batch(  # type: ignore[attr-defined]
            [ready[i.item_id][1] for i in batch], [_rng(plan, i, stage) for i in batch]
        )
    except Exception:  # noqa: BLE001 - one bad frame fails the batch: redo item by item
        frames = []
    share_ms = (time.perf_counter() - start) * 1e3 / max(len(batch), 1)
    for item, frame in zip(batch, frames, strict=False):
        partials[item.item_id] = Partial(ready[item.item_id][0], frame, first + 1)
        timings[item.item_id][f"stage:{stages[first].name}"] = share_ms
    # An item redone alone starts its timings afresh, so no step is counted twice.
    return [
        process_item(item, plan, partials[item.item_id], timings[item.item_id])
        if item.item_id in partials
        else process_item(item, plan)
        for item in items
    ]


def process_item(
    item: Item,
    plan: BuildPlan,
    partial: Partial | None = None,
    timings: dict[str, float] | None = None,
) -> dict[str, Any]:
    """Build one item and return its manifest row; never raises for a bad item.

    The outputs and provenance are written first, the journal record last, so a record
    exists only for an item whose files are complete (a killed run redoes the rest).
    A LadsError (bad input) or any other exception becomes a row with status "failed",
    except an OutputWriteError (disk full, read-only output): it stops the whole build,
    since every later item would fail the same way.
    """
    start = time.perf_counter()
    out_root = Path(plan.out_root)
    timings = {} if timings is None else timings
    try:
        frame, files, fields, (source_index, outcome, n_source) = transform(
            item, plan, timings, partial
        )
        clock = _Clock(timings)
        reader = reader_for(plan)
        row: dict[str, Any] = {
            **fields,
            "status": "ok",
            "source": _source_rows(item, reader.root)
            + window_source_rows(reader, item, frame.window, _tracked(plan)),
            "outputs": _output_rows(files),
        }
        clock.lap("hash")
        for f in files:
            atomic_write(out_root / f.relpath, f.payload)
        clock.lap("write")
        _write_provenance(out_root, item, source_index, outcome, n_source, frame)
        clock.lap("provenance")
    except OutputWriteError:
        raise
    except LadsError as exc:
        row = _failed(item, f"{type(exc).__name__}: {exc}")
    except Exception as exc:  # noqa: BLE001 - one bad frame must not end a 23k-frame build
        row = _failed(item, f"internal error {type(exc).__name__}: {exc} (please report this)")
    clock = _Clock(timings)
    atomic_write(state_path(out_root, item.item_id), json.dumps(row, sort_keys=True).encode())
    clock.lap("journal")
    row["_seconds"] = time.perf_counter() - start
    row["_step_ms"] = timings
    # ru_maxrss is in KiB on Linux: the worker's peak resident memory so far.
    row["_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return row


def _write_provenance(
    out_root: Path, item: Item, source_index: Any, outcome: Any, n: int, frame: Frame
) -> None:
    """provenance.write_item, with a write failure of the store said in words."""
    try:
        provenance.write_item(
            out_root,
            item.relpath,
            item.item_id,
            source_index,
            outcome,
            n,
            frame.window,
            frame.source_scan,
        )
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
    plan = plan_from_tree(out_root, source_root)
    wanted = set(item_ids)
    items = [i for i in reader_for(plan).items() if i.item_id in wanted]
    result: dict[str, dict[str, str]] = {}
    for item in items:
        _, files, _, _ = transform(item, plan)
        result[item.item_id] = {f.relpath: sha256_bytes(f.payload) for f in files}
    return result
