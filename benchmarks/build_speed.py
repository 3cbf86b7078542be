"""End-to-end `lads build` throughput on real SemanticKITTI frames -> build_speed.json.

The source tree is made in a temp dir from the three real SemanticKITTI frames of
../shared/data (symlinked under new frame numbers, never copied into the repo), so every
frame has real geometry, intensity and labels. Measured, for the default snow variant (the
learned intensity stage included), snow with `--intensity physics` and rain:

- frames/s of `run_build` with 1 and 2 jobs (read, stages, write, hash, provenance,
  manifest, SHA256SUMS), best of REPEATS interleaved trials after a warm-up build (the
  machine is shared; every trial is reported);
- the per-step cost per frame on one core (run_report.json `step_ms_per_item` of the best
  one-job run): read, each stage, encode, hash, write, provenance, journal;
- wall clock of the `lads build` command itself (process start, worker start, figures);
- time to the first built frame of a fresh `lads build` process;
- peak worker memory, and the 1 -> 2 job scaling;
- the Dask path on a LocalCluster (1 and 2 worker processes): frames/s and whether its tree
  has the bytes of the one-job tree;
- the nuScenes rate on a dataroot around the real keyframe (lads.synth.nuscenes tables);
- projected hours for all 23,201 labelled SemanticKITTI frames and 34,149 nuScenes
  keyframes on this machine, and a stated model for N machines with Dask.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import (
    KITTI_SCANS,
    SHARED_DATA,
    machine_info,
    reference_workload_ms,
    write_result,
)
from lads.config import PipelineConfig, pipeline_for
from lads.runner import run_build

FRAMES = 120
REPEATS = 2  # best of, as timeit does: the machine is shared
KITTI_LABELLED_FRAMES = 23_201
NUSCENES_KEYFRAMES = 34_149
VARIANTS = {"snow": {}, "snow --intensity physics": {"intensity": "physics"}, "rain": {}}
TARGETS = {
    "learned_frames_per_s_jobs_2": 25.0,
    "physics_frames_per_s_jobs_2": 40.0,
    "first_frame_s_physics": 1.5,
    "intensity_stage_ms": 35.0,
    "scaling_1_to_2": 1.8,
    "peak_worker_rss_mb": 1024.0,
}
NUSC_KEYFRAME = (
    "samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"
)


def make_tree(root: Path, frames: int) -> Path:
    seq = root / "sequences" / "00"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "labels").mkdir()
    labels = [
        SHARED_DATA / "semantickitti/sequences/00/labels" / p.with_suffix(".label").name
        for p in KITTI_SCANS
    ]
    for k in range(frames):
        (seq / "velodyne" / f"{k:06d}.bin").symlink_to(KITTI_SCANS[k % 3])
        (seq / "labels" / f"{k:06d}.label").symlink_to(labels[k % 3])
    shutil.copyfile(SHARED_DATA / "semantickitti/sequences/00/calib.txt", seq / "calib.txt")
    return root


def make_nuscenes_tree(root: Path, frames: int) -> Path:
    """`frames` keyframes, all the real nuScenes keyframe, with labels and tables."""
    from lads.synth.nuscenes import NuscSampleData, nuscenes_tables, token

    real = SHARED_DATA / "nuscenes" / NUSC_KEYFRAME
    points = np.fromfile(real, dtype="<f4").reshape(-1, 5)
    labels = np.where(np.linalg.norm(points[:, :3], axis=1) < 1.1, 31, 24).astype(np.uint8)
    records = []
    for k in range(frames):
        rel = NUSC_KEYFRAME.replace("1532402927647951", str(1532402927647951 + 500_000 * k))
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).symlink_to(real)
        tok = token(f"bench:{k}")
        seg = f"lidarseg/v1.0-mini/{tok}_lidarseg.bin"
        (root / seg).parent.mkdir(parents=True, exist_ok=True)
        labels.tofile(root / seg)
        records.append(NuscSampleData(tok, rel, True, seg))
    for rel, payload in nuscenes_tables("v1.0-mini", records).items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(payload)
    return root


def pipeline_of(variant: str, reader: str = "semantickitti") -> PipelineConfig:
    name = variant.split()[0]
    return pipeline_for(reader, name).with_overrides(**VARIANTS[variant])


def timed_build(
    source: Path, out: Path, pipeline: PipelineConfig, reader: str = "semantickitti", **kwargs: Any
) -> dict[str, Any]:
    start = time.perf_counter()
    report = run_build(reader, source, out, pipeline, seed=0, progress=False, **kwargs)
    seconds = time.perf_counter() - start
    if not report.complete:
        raise RuntimeError(f"benchmark build incomplete: {report.failed[:3]}")
    return {
        "jobs": kwargs.get("jobs", 1),
        "frames": report.built,
        "seconds": round(seconds, 3),
        "frames_per_s": round(report.built / seconds, 2),
        "peak_worker_rss_mb": round(report.peak_worker_rss_mb, 1),
        "step_ms_per_item": report.step_ms_per_item(),
    }


def _digest(root: Path) -> str:
    return (root / "SHA256SUMS").read_text()


def throughput(tmp: Path, source: Path) -> dict[str, Any]:
    """Every variant with 1 and 2 jobs, interleaved, best of REPEATS."""
    for v, variant in enumerate(VARIANTS):  # warm-up: numba caches, loky workers, models
        for jobs in (1, 2):
            timed_build(
                make_tree(tmp / f"warm_{v}_{jobs}", 6),
                tmp / f"warm_out_{v}_{jobs}",
                pipeline_of(variant),
                jobs=jobs,
            )
    trials: dict[str, dict[int, list[dict[str, Any]]]] = {v: {1: [], 2: []} for v in VARIANTS}
    for k in range(REPEATS):
        for variant in VARIANTS:
            for jobs in (1, 2):
                out = tmp / f"out_{k}_{jobs}"
                trials[variant][jobs].append(
                    timed_build(source, out, pipeline_of(variant), jobs=jobs)
                )
                shutil.rmtree(out)  # later runs must not pay for this one's disk writeback
    result = {}
    for variant, by_jobs in trials.items():
        best = {j: max(t, key=lambda r: r["frames_per_s"]) for j, t in by_jobs.items()}
        result[variant] = {
            "jobs_1": best[1],
            "jobs_2": best[2],
            "all_trials_frames_per_s": {
                f"jobs_{j}": [r["frames_per_s"] for r in t] for j, t in by_jobs.items()
            },
            "scaling_1_to_2": round(best[2]["frames_per_s"] / best[1]["frames_per_s"], 3),
            "step_ms_per_frame_one_core": best[1]["step_ms_per_item"],
        }
    return result


def command_wall(tmp: Path, source: Path, variant: str, jobs: int) -> dict[str, Any]:
    """The `lads build` command end to end: process and worker start, build, figures."""
    out = tmp / "cli_out"
    args = [
        sys.executable,
        "-m",
        "lads.cli",
        "build",
        "--source",
        "semantickitti",
        "--variant",
        *variant.split(),
        "--in",
        str(source),
        "--out",
        str(out),
        "--jobs",
        str(jobs),
    ]
    start = time.perf_counter()
    subprocess.run(args, check=True, capture_output=True)
    seconds = time.perf_counter() - start
    shutil.rmtree(out)
    return {
        "variant": variant,
        "jobs": jobs,
        "frames": FRAMES,
        "seconds": round(seconds, 2),
        "frames_per_s": round(FRAMES / seconds, 2),
    }


def first_frame_seconds(tmp: Path, source: Path, variant: str) -> float:
    """Seconds from starting `lads build` to the first item's journal record (its files
    and provenance are written before it); the process is then stopped."""
    out = tmp / "ttf_out"
    args = [
        sys.executable,
        "-m",
        "lads.cli",
        "build",
        "--source",
        "semantickitti",
        "--variant",
        *variant.split(),
        "--in",
        str(source),
        "--out",
        str(out),
    ]
    journal = out / ".lads-state" / "items"
    start = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while not (journal.is_dir() and any(journal.iterdir())):
            if proc.poll() is not None:
                raise RuntimeError(f"lads build exited with {proc.returncode} before a frame")
            time.sleep(0.005)
        return round(time.perf_counter() - start, 3)
    finally:
        proc.kill()
        proc.wait()
        shutil.rmtree(out, ignore_errors=True)


def dask_runs(tmp: Path, source: Path, reference: str) -> dict[str, Any]:
    """LocalCluster with 1 and 2 single-threaded worker processes, learned snow."""
    try:
        import distributed
    except ImportError:
        return {"skipped": "dask.distributed is not installed (pip install 'lads[dask]')"}
    rows = {}
    for workers in (1, 2):
        with distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster:
            kwargs = {"backend": "dask", "scheduler": cluster.scheduler_address}
            timed_build(
                make_tree(tmp / f"dwarm{workers}", 4),
                tmp / f"dwarm_out{workers}",
                pipeline_of("snow"),
                **kwargs,
            )
            out = tmp / f"dask_out{workers}"
            row = timed_build(source, out, pipeline_of("snow"), **kwargs)
            row["jobs"] = None
            row["dask_workers"] = workers
            row["same_bytes_as_jobs_1"] = _digest(out) == reference
            rows[f"workers_{workers}"] = row
            shutil.rmtree(out)
    return rows


def projection(
    fps_kitti: float,
    fps_nusc: float,
    dask: dict[str, Any],
    bytes_per_frame: float,
    storage_mb_s: float = 500.0,
) -> dict[str, Any]:
    """Hours per variant on this machine, and a model for N such machines with Dask."""
    eff = 1.0
    if "workers_2" in dask:
        eff = min(1.0, dask["workers_2"]["frames_per_s"] / max(fps_kitti, 1e-9))
    storage_fps = storage_mb_s * 1e6 / bytes_per_frame
    curve = {}
    for n in (1, 2, 4, 8, 16, 32, 64):
        fps = min(n * fps_kitti * eff, storage_fps)
        hours = round(KITTI_LABELLED_FRAMES / fps / 3600, 3)
        curve[str(n)] = {"frames_per_s": round(fps, 1), "hours_semantickitti": hours}
    return {
        "hours_semantickitti_23201_jobs_2": round(KITTI_LABELLED_FRAMES / fps_kitti / 3600, 2),
        "hours_nuscenes_34149_keyframes_jobs_2": round(NUSCENES_KEYFRAMES / fps_nusc / 3600, 2),
        "dask_machines_model": curve,
        "model": (
            "measured: 1 and 2 loky jobs and 1 and 2 Dask worker processes on this 2-core "
            "machine. Modelled (not measured) beyond: N machines of 2 cores each give N x the "
            "measured 2-job rate x the Dask efficiency measured here (Dask 2 workers / loky 2 "
            f"jobs = {eff:.2f}), capped by shared storage at {storage_mb_s:g} MB/s over "
            f"{bytes_per_frame / 1e6:.1f} MB read + written per frame; scheduler overhead "
            "per task (~ms) is small next to a frame's cost."
        ),
    }


def main() -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="lads_bench_") as tmp_name:
        tmp = Path(tmp_name)
        source = make_tree(tmp / "src", FRAMES)
        variants = throughput(tmp, source)
        reference_out = tmp / "reference"
        timed_build(source, reference_out, pipeline_of("snow"), jobs=1)
        reference = _digest(reference_out)
        out_bytes = sum(p.stat().st_size for p in reference_out.rglob("*") if p.is_file())
        in_bytes = sum(p.stat().st_size for p in (tmp / "src").rglob("*") if p.is_file())
        shutil.rmtree(reference_out)
        walls = [command_wall(tmp, source, "snow", 2)]
        first = {
            v: sorted(first_frame_seconds(tmp, source, v) for _ in range(3))
            for v in ("rain", "snow")
        }
        dask = dask_runs(tmp, source, reference)
        nusc = make_nuscenes_tree(tmp / "nusc", FRAMES)
        timed_build(
            make_nuscenes_tree(tmp / "nusc_warm", 6),
            tmp / "nw",
            pipeline_of("snow", "nuscenes"),
            "nuscenes",
            jobs=2,
        )
        nusc_runs = []
        for k in range(REPEATS):
            out = tmp / f"nusc_out{k}"
            nusc_runs.append(
                timed_build(nusc, out, pipeline_of("snow", "nuscenes"), "nuscenes", jobs=2)
            )
            shutil.rmtree(out)
    learned = variants["snow"]
    physics = max(
        variants["snow --intensity physics"]["jobs_2"]["frames_per_s"],
        variants["rain"]["jobs_2"]["frames_per_s"],
    )
    physics_min = min(
        variants["snow --intensity physics"]["jobs_2"]["frames_per_s"],
        variants["rain"]["jobs_2"]["frames_per_s"],
    )
    nusc_best = max(nusc_runs, key=lambda r: r["frames_per_s"])
    measured = {
        "learned_frames_per_s_jobs_2": learned["jobs_2"]["frames_per_s"],
        "physics_frames_per_s_jobs_2": physics_min,
        "first_frame_s_physics": first["rain"][1],
        "intensity_stage_ms": learned["step_ms_per_frame_one_core"].get("stage:intensity"),
        "scaling_1_to_2": learned["scaling_1_to_2"],
        "peak_worker_rss_mb": max(v["jobs_2"]["peak_worker_rss_mb"] for v in variants.values()),
    }
    met = {
        k: (
            measured[k] <= t
            if k in ("first_frame_s_physics", "intensity_stage_ms", "peak_worker_rss_mb")
            else measured[k] >= t
        )
        for k, t in TARGETS.items()
    }
    result = {
        "what": "lads build on real SemanticKITTI frames (3 real scans linked as 120 frames), "
        "end to end; snow = the default pipeline with the learned intensity stage",
        "command": "python -m benchmarks.build_speed",
        "machine": machine_info(),
        "reference_workload": reference_workload_ms(),
        "frames": FRAMES,
        "variants": variants,
        "command_wall_clock": walls,
        "first_frame_seconds": {v: {"median": t[1], "all": t} for v, t in first.items()},
        "dask_local_cluster": dask,
        "nuscenes_snow_jobs_2": nusc_best,
        "targets": TARGETS,
        "measured": measured,
        "met": met,
        "physics_fastest_frames_per_s_jobs_2": physics,
        "projection": projection(
            learned["jobs_2"]["frames_per_s"],
            nusc_best["frames_per_s"],
            dask,
            (in_bytes + out_bytes) / FRAMES,
        ),
        "note": "page cache warm (the source files are symlinks to three real KITTI frames "
        "and one real nuScenes keyframe); a cold disk adds read time",
    }
    write_result("build_speed.json", result)
    return result


if __name__ == "__main__":
    print(json.dumps(main(), indent=2))  # noqa: T201
