"""`lads build`: turn a source tree into a variant tree, on one machine or a Dask cluster.

The runner owns all I/O and parallelism; the work per item is `lads.worker.process_item`.
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

import yaml

from lads import provenance
from lads.config import PipelineConfig, parse_pipeline
from lads.errors import BuildError, ManifestError
from lads.files import atomic_copy, atomic_write, remove_stray_temps, sha256_file
from lads.finalise import (
    MANIFEST,
    NOT_SUMMED,
    PIPELINE_YAML,
    RUN_JSON,
    RUN_REPORT,
    SHA256SUMS,
    finalise,
    identity,
)
from lads.frame import Item
from lads.worker import STATE_DIR, BuildPlan, process_item, reader_for, stages_for, state_path

__all__ = [
    "MANIFEST", "NOT_SUMMED", "PIPELINE_YAML", "RUN_JSON", "RUN_REPORT", "SHA256SUMS",
    "BuildReport", "plan_from_tree", "run_build",
]  # fmt: skip

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

    @property
    def complete(self) -> bool:
        return not self.failed and not self.stopped_early

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
        return "\n".join(lines)


def freeze_options(options: dict[str, Any]) -> tuple[tuple[str, Any], ...]:
    """Reader options as sorted (key, value) pairs, lists as tuples (hashable, picklable)."""
    return tuple(
        (k, tuple(v) if isinstance(v, list | tuple) else v) for k, v in sorted(options.items())
    )


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


def _claim_output(out_root: Path, plan: BuildPlan) -> None:
    """Refuse to mix builds: OUT must be empty, or a (partial) build of the same plan."""
    ident = identity(plan)
    marker = out_root / STATE_DIR / "plan.json"
    previous: dict[str, Any] | None = None
    if marker.is_file():
        previous = json.loads(marker.read_text())
    elif (out_root / RUN_JSON).is_file():
        run = json.loads((out_root / RUN_JSON).read_text())
        previous = {k: run.get(k) for k in ident}
    elif out_root.is_dir() and any(out_root.iterdir()):
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


def _finished_rows(out_root: Path, items: list[Item]) -> dict[str, dict[str, Any]]:
    """Rows of items already built whose outputs are still intact on disk."""
    rows: dict[str, dict[str, Any]] = {}
    manifest = out_root / MANIFEST
    if manifest.is_file():
        for line in manifest.read_text().splitlines():
            row = json.loads(line)
            rows[row["item_id"]] = row
    for item in items:
        path = state_path(out_root, item.item_id)
        if path.is_file():
            rows[item.item_id] = json.loads(path.read_text())
    intact = {}
    wanted = {i.item_id for i in items}
    for item_id, row in rows.items():
        if item_id in wanted and row.get("status") == "ok" and _outputs_intact(out_root, row):
            intact[item_id] = row
    return intact


def _outputs_intact(out_root: Path, row: dict[str, Any]) -> bool:
    for out in row["outputs"]:
        path = out_root / out["path"]
        if (
            not path.is_file()
            or path.stat().st_size != out["bytes"]
            or sha256_file(path) != out["sha256"]
        ):
            return False
    return True


def _copy_files(reader: Any, source_root: Path, out_root: Path) -> list[dict[str, Any]]:
    rows = []
    for rel in sorted(reader.copied_files()):
        src, dst = source_root / rel, out_root / rel
        digest = sha256_file(src)
        if not (dst.is_file() and sha256_file(dst) == digest):
            atomic_copy(src, dst)
        rows.append({"path": rel, "bytes": src.stat().st_size, "sha256": digest})
    return rows


def _dispatch(todo: list[Item], plan: BuildPlan, jobs: int, backend: str, scheduler: str | None):  # type: ignore[no-untyped-def]
    """Yield manifest rows as items finish (any order)."""
    if jobs == 1 and backend == "loky":
        for item in todo:
            yield process_item(item, plan)
        return
    from joblib import Parallel, delayed, parallel_config

    if backend == "dask":
        try:
            from distributed import Client
        except ImportError as exc:
            raise BuildError(
                "--backend dask needs dask.distributed: pip install 'lads[dask]'."
            ) from exc
        client = Client(scheduler) if scheduler else Client(processes=False)
        try:
            with parallel_config(backend="dask"):
                yield from Parallel(n_jobs=-1, return_as="generator_unordered")(
                    delayed(process_item)(item, plan) for item in todo
                )
        finally:
            client.close()
        return
    # One thread per worker: the workers are the parallelism, and a fixed thread count
    # keeps float reductions in a fixed order.
    with parallel_config(backend=backend, n_jobs=jobs, inner_max_num_threads=1):
        yield from Parallel(return_as="generator_unordered")(
            delayed(process_item)(item, plan) for item in todo
        )


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

    Returns:
        BuildReport; `complete` is False when any item failed.

    Raises:
        BuildError: output inside the source, a conflicting existing tree, or (fail_fast)
            the first failed item. ConfigError/ReaderError for bad settings or source trees.
    """
    from tqdm import tqdm

    start = time.perf_counter()
    source_root, out_root = Path(source_root).resolve(), Path(out_root).resolve()
    _check_paths(source_root, out_root)
    options = freeze_options(reader_options or {})
    plan = BuildPlan(source, str(source_root), str(out_root), options, pipeline, seed)
    pipeline.check_source(source, f"pipeline '{pipeline.variant}'")
    stages_for(pipeline)  # a bad stage (e.g. missing weights) stops here, before any output
    reader = reader_for(plan)
    items = reader.items()[:limit] if limit else reader.items()
    out_root.mkdir(parents=True, exist_ok=True)
    _claim_output(out_root, plan)
    remove_stray_temps(out_root)
    copied = _copy_files(reader, Path(reader.root), out_root)
    provenance.create_store(
        out_root, points_mode=pipeline.points, config_hash=pipeline.config_hash()
    )
    done = _finished_rows(out_root, items)
    todo = [i for i in items if i.item_id not in done]
    report = BuildReport(out_root, items=len(items), built=0, skipped=len(done))
    rows = dict(done)
    seconds: list[float] = []
    bar = tqdm(
        total=len(todo),
        unit="scan",
        desc=f"{source} {pipeline.variant}",
        disable=None if progress is None else not progress,
    )
    with bar:
        for row in _dispatch(todo, plan, jobs, backend, scheduler):
            seconds.append(row.pop("_seconds", 0.0))
            report.peak_worker_rss_mb = max(report.peak_worker_rss_mb, row.pop("_peak_rss_mb", 0.0))
            rows[row["item_id"]] = row
            bar.update(1)
            if row["status"] == "ok":
                report.built += 1
                continue
            report.failed.append((row["item_id"], row["error"]))
            if fail_fast:
                report.stopped_early = True
                break
    report.seconds = time.perf_counter() - start
    if report.stopped_early:
        _write_report(out_root, report, seconds)
        item_id, error = report.failed[0]
        raise BuildError(
            f"{item_id}: {error} (stopped by --fail-fast; fix it and run again to resume)"
        )
    finalise(out_root, plan, items, rows, copied, figures=figures)
    report.seconds = time.perf_counter() - start
    _write_report(out_root, report, seconds)
    return report


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
        "item_seconds_median": round(sorted(seconds)[len(seconds) // 2], 4) if seconds else None,
    }
    atomic_write(out_root / RUN_REPORT, (json.dumps(data, indent=1) + "\n").encode())


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
