"""End-to-end `lads build` throughput on SemanticKITTI-sized frames, 1 and 2 jobs.

The source tree is made in a temp dir from the three real SemanticKITTI frames of
../shared/data (symlinked under new frame numbers, never copied into the repo), so every
frame has real geometry, intensity and labels. Timed: read, snow stage, write, hash,
provenance, manifest and SHA256SUMS: the whole `run_build`. Each configuration runs REPEATS
times, interleaved, after a warm-up build (numba caches, loky workers), as a long build
would; the best and every trial are reported, since the machine is shared.

Writes benchmarks/results/build_speed.json: frames/s for --jobs 1 and 2, the scaling ratio,
peak worker memory, and the projected hours for all 23,201 labelled SemanticKITTI frames and
34,149 nuScenes keyframes. The nuScenes rate is measured the same way on a dataroot of JSON
tables (lads.synth.nuscenes) around the real 34,688-point keyframe of ../shared/data, linked
under new timestamps, each with a generated uint8 lidarseg file.
"""

from __future__ import annotations

import json
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import KITTI_SCANS, SHARED_DATA, machine_info, write_result
from lads.config import find_pipeline, load_pipeline
from lads.runner import run_build

FRAMES = 300
REPEATS = 3  # best of, as timeit does: the machine is shared
KITTI_LABELLED_FRAMES = 23_201
NUSCENES_KEYFRAMES = 34_149


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


NUSC_KEYFRAME = (
    "samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"
)


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


def timed_build(
    source: Path, out: Path, jobs: int, reader: str = "semantickitti"
) -> dict[str, Any]:
    # The weather path as in issue 5 (physics intensity); the learned intensity stage is
    # timed on its own in intensity_speed.json.
    pipeline = load_pipeline(find_pipeline(reader, "snow")).with_overrides(intensity="physics")
    start = time.perf_counter()
    report = run_build(reader, source, out, pipeline, seed=0, jobs=jobs, progress=False)
    seconds = time.perf_counter() - start
    if not report.complete:
        raise RuntimeError(f"benchmark build incomplete: {report.failed[:3]}")
    points = sum(
        json.loads(line)["points"]["source"]
        for line in (out / "manifest.jsonl").read_text().splitlines()
    )
    return {
        "jobs": jobs,
        "frames": report.built,
        "seconds": round(seconds, 3),
        "frames_per_s": round(report.built / seconds, 2),
        "points_per_s": round(points / seconds),
        "peak_worker_rss_mb": round(report.peak_worker_rss_mb, 1),
    }


def main() -> dict[str, Any]:
    trials: dict[int, list[dict[str, Any]]] = {1: [], 2: []}
    with tempfile.TemporaryDirectory(prefix="lads_bench_") as tmp:
        source = make_tree(Path(tmp) / "src", FRAMES)
        for jobs in (1, 2):
            timed_build(
                make_tree(Path(tmp) / f"warm{jobs}", 6), Path(tmp) / f"warm_out{jobs}", jobs
            )
        # Interleaved, each output deleted after its run: otherwise later runs pay for the
        # disk writeback of earlier ones, which biases whichever configuration runs last.
        for k in range(REPEATS):
            for jobs in (1, 2):
                out = Path(tmp) / f"out{jobs}_{k}"
                trials[jobs].append(timed_build(source, out, jobs))
                shutil.rmtree(out)
        runs = {jobs: max(t, key=lambda r: r["frames_per_s"]) for jobs, t in trials.items()}
        nusc = make_nuscenes_tree(Path(tmp) / "nusc", FRAMES)
        timed_build(make_nuscenes_tree(Path(tmp) / "nusc_warm", 6), Path(tmp) / "nw", 2, "nuscenes")
        nusc_trials = []
        for k in range(REPEATS):
            nusc_trials.append(timed_build(nusc, Path(tmp) / f"nusc_out{k}", 2, "nuscenes"))
            shutil.rmtree(Path(tmp) / f"nusc_out{k}")
        nusc_run = max(nusc_trials, key=lambda r: r["frames_per_s"])
    best = runs[2]
    kitti_pts = best["points_per_s"] / best["frames_per_s"]
    nusc_fps = nusc_run["frames_per_s"]
    result = {
        "what": "lads build, SemanticKITTI snow 2.5 mm/h, physical points, end to end",
        "command": "python -m benchmarks.build_speed",
        "machine": machine_info(),
        "frames": FRAMES,
        "jobs_1": runs[1],
        "jobs_2": runs[2],
        "all_trials_frames_per_s": {
            f"jobs_{j}": [r["frames_per_s"] for r in t] for j, t in trials.items()
        },
        "scaling_1_to_2": round(runs[2]["frames_per_s"] / runs[1]["frames_per_s"], 3),
        "scaling_1_to_2_of_medians": round(
            statistics.median(r["frames_per_s"] for r in trials[2])
            / statistics.median(r["frames_per_s"] for r in trials[1]),
            3,
        ),
        "targets": {"frames_per_s_jobs_2": 20.0, "scaling": 1.7, "peak_worker_rss_mb": 1024},
        "nuscenes_jobs_2": nusc_run,
        "mean_points_per_frame": round(kitti_pts),
        "projected_hours_semantickitti_23201": round(
            KITTI_LABELLED_FRAMES / best["frames_per_s"] / 3600, 2
        ),
        "projected_hours_nuscenes_34149_keyframes": round(NUSCENES_KEYFRAMES / nusc_fps / 3600, 2),
        "projection_note": "hours = frame count / measured frames/s with --jobs 2 on 2 cores, "
        "page cache warm (the source files are symlinks to three real KITTI frames and one real "
        "nuScenes keyframe); a cold disk adds read time",
    }
    write_result("build_speed.json", result)
    return result


if __name__ == "__main__":
    print(json.dumps(main(), indent=2))  # noqa: T201
