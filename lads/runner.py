"""`lads build`: turn a source tree into a variant tree, on one machine or a Dask cluster.

The runner owns all I/O and parallelism: it claims the output folder (`lads.output_tree`),
spreads the items over workers (`lads.dispatch`) and finalises the tree; the work per item
is `lads.worker.process_item` (`process_items` for a batch).
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
    RUN_REPORT,
    SHA256SUMS,
    BuildPlan,
    freeze_options,
)
from lads.config import PipelineConfig
from lads.dispatch import check_backend, default_batch, dispatch
from lads.errors import BuildError, ConfigError, OutputWriteError
from lads.files import atomic_write, make_folder, remove_stray_temps, write_error
from lads.finalise import finalise
from lads.frame import Item
from lads.lock import output_lock
from lads.output_tree import check_paths, claim_output, copy_source_files
from lads.resume import finished_rows
from lads.stages import check_sensor
from lads.worker import reader_for, stages_for

__all__ = ["BuildReport", "run_build"]

log = logging.getLogger(__name__)


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
    # (items in the tree, items of the source) when a --limit trial left some out, else None
    subset: tuple[int, int] | None = None

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
        if self.subset is not None:
            state += f" (a trial subset: {self.subset[0]} of the source's {self.subset[1]} items)"
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
    settings = _RunSettings(jobs, backend, scheduler, fail_fast, progress, figures, batch, limit)
    source_root, out_root = Path(source_root).resolve(), Path(out_root).resolve()
    plan, reader, items = _plan_build(source, source_root, out_root, pipeline, seed, reader_options)
    make_folder(out_root)
    with output_lock(out_root, "build", wait=wait):
        report = _build_and_report(plan, reader, items, settings, start)
    if report.stopped_early:
        raise _fail_fast_error(report)
    return report


def _check_count(name: str, value: int | None, least: int) -> None:
    """ConfigError unless value is None or an integer >= least: seeds derive numpy
    SeedSequences (which need one >= 0), and a limit of -1 would drop the last item."""
    if value is not None and (
        isinstance(value, bool) or not isinstance(value, int) or value < least
    ):
        raise ConfigError(f"{name} {value!r}: expected an integer >= {least}.")


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
    limit: int | None

    def __post_init__(self) -> None:
        _check_count("jobs", self.jobs, 1)
        _check_count("batch", self.batch, 1)
        _check_count("limit", self.limit, 1)
        check_backend(self.backend, self.scheduler)


def _plan_build(
    source: str,
    source_root: Path,
    out_root: Path,
    pipeline: PipelineConfig,
    seed: int,
    reader_options: dict[str, Any] | None,
) -> tuple[BuildPlan, Any, list[Item]]:
    """The checked build plan, its reader and every item of the source (sorted)."""
    _check_count("seed", seed, 0)
    check_paths(source_root, out_root)
    options = freeze_options(reader_options or {})
    plan = BuildPlan(source, str(source_root), str(out_root), options, pipeline, seed)
    pipeline.check_source(source, f"pipeline '{pipeline.variant}'")
    stages = stages_for(pipeline)  # a bad stage (e.g. missing weights) stops here, before output
    reader = reader_for(plan)
    check_sensor(stages, pipeline.output_sensor(reader.sensor))
    return plan, reader, reader.items()


def _build_and_report(
    plan: BuildPlan, reader: Any, items: list[Item], settings: _RunSettings, start: float
) -> BuildReport:
    """The BuildReport of the build (lock held), also written to run_report.json."""
    out_root = Path(plan.out_root)
    wanted = len(items[: settings.limit]) if settings.limit else len(items)
    report = BuildReport(out_root, items=wanted, built=0, skipped=0)
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
            limit=settings.limit,
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
    limit: int | None,
) -> None:
    """The build proper, with the output's lock held: claim, clean, copy, build, finalise.

    `items` are every item of the source; the first `limit` are built. Items an earlier
    build of the same settings finished stay in the tree even beyond the limit (a smaller
    trial after a larger one keeps the larger one's items)."""
    from tqdm import tqdm

    out_root = Path(plan.out_root)
    copied = _prepare_output(plan, reader)
    versions = [(stage.name, stage.version) for stage in stages_for(plan.pipeline)]
    done = finished_rows(out_root, Path(reader.root), items, versions)
    wanted = items[:limit] if limit else items
    todo = [i for i in wanted if i.item_id not in done]
    report.skipped = len(wanted) - len(todo)
    rows = dict(done)
    ids = {i.item_id for i in wanted} | set(done)
    kept = [i for i in items if i.item_id in ids]
    bar = tqdm(
        total=len(todo),
        unit="scan",
        desc=f"{plan.source} {plan.pipeline.variant}",
        disable=None if progress is None else not progress,
    )
    with bar:
        for row in dispatch(todo, plan, jobs, backend, scheduler, batch):
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
    report.subset = (len(kept), len(items)) if len(kept) < len(items) else None
    report.foreign = finalise(
        out_root, plan, kept, rows, copied, figures=figures, limit=limit, source_items=len(items)
    )


def _prepare_output(plan: BuildPlan, reader: Any) -> list[dict[str, Any]]:
    """Claim OUT for this plan, clear a crashed run's temp files, copy the source's side
    files and open the provenance store; returns the copied files' entries."""
    out_root = Path(plan.out_root)
    claim_output(out_root, plan)
    remove_stray_temps(out_root)
    copied = copy_source_files(reader, Path(reader.root), out_root)
    try:
        provenance.create_store(
            out_root, points_mode=plan.pipeline.points, config_hash=plan.pipeline.config_hash()
        )
    except OSError as exc:
        raise write_error(out_root / provenance.STORE_NAME, exc) from exc
    return copied


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
        "subset": report.subset and {"items": report.subset[0], "of": report.subset[1]},
        "item_seconds_median": round(sorted(seconds)[len(seconds) // 2], 4) if seconds else None,
        "step_ms_per_item": report.step_ms_per_item(),
    }
    atomic_write(out_root / RUN_REPORT, (json.dumps(data, indent=1) + "\n").encode())
