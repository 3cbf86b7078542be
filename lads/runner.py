"""`lads build`: turn a source tree into a variant tree, on one machine or a Dask cluster.

The runner owns all I/O and parallelism; the work per item is `lads.worker.process_item`
(`process_items` for a batch).
A killed build resumes: finished items are journaled under OUT/.lads-state and re-checked
(their output hashes) before being skipped, so the finished tree is byte-identical to an
uninterrupted build whatever the job count, order or backend.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lads import provenance
from lads.built_tree import (
    PLAN_JSON,
    RUN_JSON,
    RUN_REPORT,
    SHA256SUMS,
    STATE_DIR,
    BuildPlan,
    freeze_options,
    identity,
)
from lads.config import PipelineConfig
from lads.errors import BuildError, OutputWriteError
from lads.files import atomic_copy, atomic_write, remove_stray_temps, sha256_file, write_error
from lads.finalise import finalise
from lads.frame import Item
from lads.lock import LOCK_NAME, output_lock
from lads.readers.base import unreadable_reason
from lads.resume import finished_rows
from lads.worker import process_items, reader_for, stages_for

__all__ = ["BuildReport", "run_build"]

log = logging.getLogger(__name__)

GPU_BATCH = 8  # frames per forward pass on a GPU (~0.3 GB of activations at 64 x 2048)


@dataclass(slots=True)
class BuildReport:
    """What one `run_build` call did."""

    out_root: Path
    items: int
    built: int
    skipped: int
    failed: list[tuple[str, str]] = field(default_factory=list)
    seconds: float = 0.0
    stopped_early: bool = False
    peak_worker_rss_mb: float = 0.0
    foreign: list[str] = field(default_factory=list)
    step_ms: dict[str, float] = field(default_factory=dict)  # summed over the items built

    def step_ms_per_item(self) -> dict[str, float]:
        """Mean worker milliseconds per processed item of each step (read, stage:NAME,
        encode, hash, write, provenance, journal), in the order the steps run."""
        done = self.built + len(self.failed)
        return {k: round(v / done, 2) for k, v in self.step_ms.items()} if done else {}

    @property
    def complete(self) -> bool:
        return not self.failed and not self.stopped_early and not self.foreign

    @property
    def frames_per_s(self) -> float:
        return self.built / self.seconds if self.seconds > 0 else 0.0

    def summary_text(self) -> str:
        state = "complete" if self.complete else "INCOMPLETE"
        lines = [
            f"{self.out_root}: {state}",
            f"  items {self.items}  built {self.built}  skipped (already done) {self.skipped}  "
            f"failed {len(self.failed)}",
            f"  {self.seconds:.1f} s, {self.frames_per_s:.1f} frames/s",
        ]
        lines += [f"  FAILED {item_id}: {error}" for item_id, error in self.failed[:20]]
        if len(self.failed) > 20:
            lines.append(f"  ... and {len(self.failed) - 20} more in {RUN_REPORT}")
        if self.foreign:
            lines.append(
                f"  {len(self.foreign)} files in the output were not written by this build and "
                f"are left out of {SHA256SUMS} (lads verify reports them): move them out of "
                "the tree, then run again"
            )
            lines += [f"  FOREIGN {rel}" for rel in self.foreign[:20]]
        return "\n".join(lines)


def _check_paths(source_root: Path, out_root: Path) -> None:
    src, out = source_root.resolve(), out_root.resolve()
    if out == src or src in out.parents:
        raise BuildError(
            f"{out_root}: the output directory is inside the source tree {source_root}; lads never "
            "writes into a source dataset. Choose an --out outside it."
        )
    if out in src.parents:
        raise BuildError(
            f"{out_root}: the output directory contains the source tree {source_root}; choose an "
            "--out that is neither inside nor around the source."
        )


def _make_output(out_root: Path) -> None:
    """Create OUT (and its parents) or say in words why it cannot be created."""
    try:
        out_root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise write_error(out_root, exc) from exc


def _previous_identity(path: Path, ident: dict[str, Any]) -> dict[str, Any]:
    """The build identity recorded in OUT's plan.json or run.json, or a BuildError when the
    file is not a lads record (not JSON, or JSON without the identity keys)."""
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BuildError(
            f"{path}: not a lads build record ({exc}); the output folder holds something lads "
            "did not write, or a damaged build. Choose an empty --out, or delete the folder "
            "to rebuild."
        ) from exc
    if not isinstance(record, dict) or "config_hash" not in record or "source" not in record:
        raise BuildError(
            f"{path}: a JSON file lads did not write (no source and config_hash); the output "
            "folder is not a lads build. Choose an empty or new --out."
        )
    return {k: record.get(k) for k in ident}


def _claim_output(out_root: Path, plan: BuildPlan) -> None:
    """Refuse to mix builds: OUT must be empty, or a (partial) build of the same plan."""
    ident = identity(plan)
    marker = out_root / STATE_DIR / PLAN_JSON
    previous: dict[str, Any] | None = None
    if marker.is_file():
        previous = _previous_identity(marker, ident)
    elif (out_root / RUN_JSON).exists():
        previous = _previous_identity(out_root / RUN_JSON, ident)
    elif any(p.name != LOCK_NAME for p in out_root.iterdir()):
        raise BuildError(
            f"{out_root}: the directory is not empty and holds no lads build; choose an empty or "
            "new --out."
        )
    if previous is not None and previous != ident:
        diff = sorted(k for k in ident if previous.get(k) != ident[k])
        raise BuildError(
            f"{out_root}: holds a build with other settings ({', '.join(diff)} differ); use "
            "another --out, or delete it to rebuild."
        )
    atomic_write(marker, json.dumps(ident, sort_keys=True).encode())


def _copy_files(reader: Any, source_root: Path, out_root: Path) -> list[dict[str, Any]]:
    rows = []
    for rel in sorted(reader.copied_files()):
        src, dst = source_root / rel, out_root / rel
        try:
            digest, size = sha256_file(src), src.stat().st_size
        except OSError as exc:
            raise BuildError(
                f"{src}: a file the build copies byte for byte cannot be read "
                f"({unreadable_reason(src, exc)}); restore it in the source, then run again."
            ) from exc
        if not (dst.is_file() and sha256_file(dst) == digest):
            atomic_copy(src, dst)
        rows.append({"path": rel, "bytes": size, "sha256": digest})
    return rows


def _dispatch(  # type: ignore[no-untyped-def]
    todo: list[Item],
    plan: BuildPlan,
    jobs: int,
    backend: str,
    scheduler: str | None,
    batch: int = 1,
):
    """Yield manifest rows as items finish (any order); `batch` items per task."""
    tasks = [todo[k : k + batch] for k in range(0, len(todo), max(batch, 1))]
    if jobs == 1 and backend == "loky":
        for task in tasks:
            yield from process_items(task, plan)
        return
    if backend == "dask":
        try:
            from distributed import Client, as_completed
        except ImportError as exc:
            raise BuildError(
                "--backend dask needs dask.distributed: pip install 'lads[dask]'."
            ) from exc
        client = Client(scheduler) if scheduler else Client(processes=False)
        try:
            # Plain futures: joblib's dask backend kept the client process busy, which on a
            # small machine took a core from the workers (2 workers ran slower than 1).
            shared = client.scatter(plan, broadcast=True)
            futures = client.map(process_items, tasks, plan=shared, pure=False)
            for future in as_completed(futures):
                yield from future.result()
        finally:
            client.close()
        return
    from joblib import Parallel, delayed, parallel_config

    # One thread per worker: the workers are the parallelism, and a fixed thread count
    # keeps float reductions in a fixed order.
    with parallel_config(backend=backend, n_jobs=jobs, inner_max_num_threads=1):
        for rows in Parallel(return_as="generator_unordered")(
            delayed(process_items)(task, plan) for task in tasks
        ):
            yield from rows


def default_batch(pipeline: PipelineConfig) -> int:
    """Frames per task: GPU_BATCH when a stage runs on a GPU (its batched forward pass),
    else 1 (on a CPU a batch saves nothing and delays the progress bar)."""
    on_gpu = any(str(s.params.get("device", "cpu")).startswith("cuda") for s in pipeline.stages)
    return GPU_BATCH if on_gpu else 1


def run_build(
    source: str,
    source_root: Path,
    out_root: Path,
    pipeline: PipelineConfig,
    *,
    seed: int = 0,
    reader_options: dict[str, Any] | None = None,
    jobs: int = 1,
    backend: str = "loky",
    scheduler: str | None = None,
    fail_fast: bool = False,
    progress: bool | None = None,
    limit: int | None = None,
    figures: bool = False,
    wait: bool = False,
    batch: int | None = None,
) -> BuildReport:
    """Build (or resume building) the variant tree `out_root` from `source_root`.

    Args:
        source: reader name (`lads.readers.READERS`).
        pipeline: the effective pipeline (after overrides).
        seed: root seed; every item's randomness derives from (seed, item, variant, stage).
        reader_options: passed to the reader (e.g. sequences, version, include_sweeps).
        jobs: worker processes for the loky backend (1 = in this process).
        backend: "loky" or "dask" (then `scheduler` is the address of a running
            distributed scheduler; None starts an in-process cluster).
        fail_fast: stop at the first failed item instead of recording it and going on.
        progress: tqdm bar; None = only when stderr is a terminal.
        limit: build only the first `limit` items (sorted), for trials.
        figures: draw OUT/figures/preview.png (source vs variant of the first item) for
            the dataset card; about a second per build.
        wait: when another lads process holds the output's lock, wait for it instead of
            refusing at once.
        batch: frames per task; a learned stage runs them in one forward pass. None:
            `default_batch` (GPU_BATCH on a GPU, else 1). Output bytes do not depend on it.

    Returns:
        BuildReport; `complete` is False when any item failed or the tree holds files lads
        did not write.

    Raises:
        BuildError: output inside the source, a conflicting or foreign tree, another build
            holding the output (`lads.lock.OutputLockedError`), a full or read-only output
            (`OutputWriteError`, after writing run_report.json where it can), or (fail_fast)
            the first failed item. ConfigError/ReaderError for bad settings or source trees.
    """
    start = time.perf_counter()
    source_root, out_root = Path(source_root).resolve(), Path(out_root).resolve()
    plan, reader, items = _plan_build(
        source, source_root, out_root, pipeline, seed, reader_options, limit
    )
    _make_output(out_root)
    settings = _RunSettings(jobs, backend, scheduler, fail_fast, progress, figures, batch)
    with output_lock(out_root, "build", wait=wait):
        report = _build_and_report(plan, reader, items, settings, start)
    if report.stopped_early:
        raise _fail_fast_error(report)
    return report


@dataclass(frozen=True, slots=True)
class _RunSettings:
    """How `run_build` runs the items (its arguments of the same names; batch None: default)."""

    jobs: int
    backend: str
    scheduler: str | None
    fail_fast: bool
    progress: bool | None
    figures: bool
    batch: int | None


def _plan_build(
    source: str,
    source_root: Path,
    out_root: Path,
    pipeline: PipelineConfig,
    seed: int,
    reader_options: dict[str, Any] | None,
    limit: int | None,
) -> tuple[BuildPlan, Any, list[Item]]:
    """The checked build plan, its reader and the items to build (the first `limit`)."""
    _check_paths(source_root, out_root)
    options = freeze_options(reader_options or {})
    plan = BuildPlan(source, str(source_root), str(out_root), options, pipeline, seed)
    pipeline.check_source(source, f"pipeline '{pipeline.variant}'")
    stages_for(pipeline)  # a bad stage (e.g. missing weights) stops here, before any output
    reader = reader_for(plan)
    items = reader.items()[:limit] if limit else reader.items()
    return plan, reader, items


def _build_and_report(
    plan: BuildPlan, reader: Any, items: list[Item], settings: _RunSettings, start: float
) -> BuildReport:
    """The BuildReport of the build (lock held), also written to run_report.json."""
    out_root = Path(plan.out_root)
    report = BuildReport(out_root, items=len(items), built=0, skipped=0)
    seconds: list[float] = []
    try:
        _build_locked(
            plan,
            reader,
            items,
            report,
            seconds,
            jobs=settings.jobs,
            backend=settings.backend,
            scheduler=settings.scheduler,
            fail_fast=settings.fail_fast,
            progress=settings.progress,
            figures=settings.figures,
            batch=default_batch(plan.pipeline) if settings.batch is None else settings.batch,
        )
    except (OutputWriteError, KeyboardInterrupt):
        report.stopped_early = True
        report.seconds = time.perf_counter() - start
        _try_report(out_root, report, seconds)
        remove_stray_temps(out_root)  # ours: the lock keeps every other run out
        raise
    report.seconds = time.perf_counter() - start
    _write_report(out_root, report, seconds)
    return report


def _fail_fast_error(report: BuildReport) -> BuildError:
    """The BuildError of a build --fail-fast stopped, naming its first failed item."""
    item_id, error = report.failed[0]
    return BuildError(
        f"{item_id}: {error} (stopped by --fail-fast; fix it and run again to resume)"
    )


def _build_locked(
    plan: BuildPlan,
    reader: Any,
    items: list[Item],
    report: BuildReport,
    seconds: list[float],
    *,
    jobs: int,
    backend: str,
    scheduler: str | None,
    fail_fast: bool,
    progress: bool | None,
    figures: bool,
    batch: int,
) -> None:
    """The build proper, with the output's lock held: claim, clean, copy, build, finalise."""
    from tqdm import tqdm

    out_root = Path(plan.out_root)
    _claim_output(out_root, plan)
    remove_stray_temps(out_root)
    copied = _copy_files(reader, Path(reader.root), out_root)
    try:
        provenance.create_store(
            out_root, points_mode=plan.pipeline.points, config_hash=plan.pipeline.config_hash()
        )
    except OSError as exc:
        raise write_error(out_root / provenance.STORE_NAME, exc) from exc
    done = finished_rows(out_root, Path(reader.root), items)
    todo = [i for i in items if i.item_id not in done]
    report.skipped = len(done)
    rows = dict(done)
    bar = tqdm(
        total=len(todo),
        unit="scan",
        desc=f"{plan.source} {plan.pipeline.variant}",
        disable=None if progress is None else not progress,
    )
    with bar:
        for row in _dispatch(todo, plan, jobs, backend, scheduler, batch):
            seconds.append(row.pop("_seconds", 0.0))
            for step, ms in row.pop("_step_ms", {}).items():
                report.step_ms[step] = report.step_ms.get(step, 0.0) + ms
            report.peak_worker_rss_mb = max(report.peak_worker_rss_mb, row.pop("_peak_rss_mb", 0.0))
            rows[row["item_id"]] = row
            bar.update(1)
            if row["status"] == "ok":
                report.built += 1
                continue
            report.failed.append((row["item_id"], row["error"]))
            if fail_fast:
                report.stopped_early = True
                return
    report.foreign = finalise(out_root, plan, items, rows, copied, figures=figures)


def _try_report(out_root: Path, report: BuildReport, seconds: list[float]) -> None:
    """Write run_report.json if the disk still lets us (a full disk may not)."""
    try:
        _write_report(out_root, report, seconds)
    except (OutputWriteError, OSError):
        log.warning("%s: run_report.json could not be written", out_root)


def _write_report(out_root: Path, report: BuildReport, seconds: list[float]) -> None:
    data = {
        "complete": report.complete,
        "items": report.items,
        "built": report.built,
        "skipped": report.skipped,
        "failed": [{"item_id": i, "error": e} for i, e in report.failed],
        "stopped_early": report.stopped_early,
        "seconds": round(report.seconds, 3),
        "frames_per_s": round(report.frames_per_s, 3),
        "peak_worker_rss_mb": round(report.peak_worker_rss_mb, 1),
        "foreign_files": report.foreign,
        "item_seconds_median": round(sorted(seconds)[len(seconds) // 2], 4) if seconds else None,
        "step_ms_per_item": report.step_ms_per_item(),
    }
    atomic_write(out_root / RUN_REPORT, (json.dumps(data, indent=1) + "\n").encode())
