"""`lads build --variant sensor-hdl32e` end to end -> sensor_build_speed.json.

A synthetic HDL-64E street (`lads.synth`, SemanticKITTI layout with poses.txt and calib.txt)
is built as the HDL-32E with the shipped 10-scan window: frames/s with 1 and 2 jobs (best of
REPEATS after a warm-up), the per-step cost per frame on one core, peak worker memory, and
the Dask path on a LocalCluster (1 and 2 single-threaded worker processes), whose tree must
hold the bytes of the one-job tree. Target: 5 frames/s per core (issue 30).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.build_speed import timed_build
from benchmarks.common import machine_info, write_result
from lads.config import pipeline_for
from lads.synth.writer import write_synthetic_dataset

FRAMES = 40
REPEATS = 2
TARGET_FRAMES_PER_S_ONE_CORE = 5.0
VARIANT = "sensor-hdl32e"


def _digest(root: Path) -> str:
    return (root / "SHA256SUMS").read_text()


def _trials(source: Path, tmp: Path) -> dict[str, Any]:
    pipeline = pipeline_for("semantickitti", VARIANT)
    timed_build(source, tmp / "warm", pipeline, jobs=1, limit=4)  # numba caches, imports
    runs: dict[int, list[dict[str, Any]]] = {1: [], 2: []}
    reference = ""
    for k in range(REPEATS):
        for jobs in (1, 2):
            out = tmp / f"out_{k}_{jobs}"
            runs[jobs].append(timed_build(source, out, pipeline, jobs=jobs, figures=False))
            if jobs == 1 and not reference:
                reference = _digest(out)
            runs[jobs][-1]["same_bytes_as_jobs_1"] = _digest(out) == reference
            shutil.rmtree(out)
    best = {j: max(t, key=lambda r: r["frames_per_s"]) for j, t in runs.items()}
    return {
        "jobs_1": best[1],
        "jobs_2": best[2],
        "all_trials_frames_per_s": {
            f"jobs_{j}": [r["frames_per_s"] for r in t] for j, t in runs.items()
        },
        "reference_sha256sums": reference,
    }


def _dask(source: Path, tmp: Path, reference: str) -> dict[str, Any]:
    try:
        import distributed
    except ImportError:
        return {"skipped": "dask.distributed is not installed (pip install 'lads[dask]')"}
    pipeline = pipeline_for("semantickitti", VARIANT)
    rows = {}
    for workers in (1, 2):
        with distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster:
            kwargs = {"backend": "dask", "scheduler": cluster.scheduler_address}
            out = tmp / f"dask_{workers}"
            row = timed_build(source, out, pipeline, figures=False, **kwargs)
            row.update(
                jobs=None, dask_workers=workers, same_bytes_as_jobs_1=_digest(out) == reference
            )
            rows[f"workers_{workers}"] = row
            shutil.rmtree(out)
    return rows


def markdown(result: dict[str, Any]) -> str:
    one, two = result["build"]["jobs_1"], result["build"]["jobs_2"]
    lines = [
        f"# `lads build --variant {VARIANT}`: {FRAMES} synthetic HDL-64E frames, 10-scan window",
        "",
        f"- one job: {one['frames_per_s']:.2f} frames/s (target "
        f"{TARGET_FRAMES_PER_S_ONE_CORE:g} per core); two jobs: {two['frames_per_s']:.2f}",
        f"- per step on one core (ms/frame): {one['step_ms_per_item']}",
        f"- peak worker memory: {one['peak_worker_rss_mb']:.0f} MB (one job)",
        f"- two jobs write the one-job bytes: {two['same_bytes_as_jobs_1']}",
    ]
    for name, row in result["dask_local_cluster"].items():
        if isinstance(row, dict):
            lines.append(
                f"- Dask {name}: {row['frames_per_s']:.2f} frames/s, same bytes: "
                f"{row['same_bytes_as_jobs_1']}"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--results", type=Path, default=None)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="lads_sensor_speed_") as name:
        tmp = Path(name)
        source = tmp / "src"
        write_synthetic_dataset(source, frames=FRAMES)
        build = _trials(source, tmp)
        dask = _dask(source, tmp, build.pop("reference_sha256sums"))
    result = {
        "machine": machine_info(),
        "variant": VARIANT,
        "frames": FRAMES,
        "target_frames_per_s_one_core": TARGET_FRAMES_PER_S_ONE_CORE,
        "build": build,
        "dask_local_cluster": dask,
        "meets_target": build["jobs_1"]["frames_per_s"] >= TARGET_FRAMES_PER_S_ONE_CORE,
    }
    path = write_result("sensor_build_speed.json", result, args.results)
    path.with_suffix(".md").write_text(markdown(result))
    print(markdown(result))


if __name__ == "__main__":
    main()
