"""Milliseconds per real SemanticKITTI frame for rain, snow and fog, on one core.

Run: .venv/bin/python -m benchmarks.speed   (writes benchmarks/results/speed.json)
"""

from __future__ import annotations

import os

# One core, as the target says: pin every thread pool before numpy/numba load.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import math  # noqa: E402
import mmap  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from benchmarks.common import (  # noqa: E402
    kitti_frames,
    kitti_labels,
    machine_info,
    reference_workload_ms,
    write_result,
)
from lads.physics import weather  # noqa: E402
from lads.physics.wet_ground import WetGroundParams, wet_ground  # noqa: E402
from lads.sensors.profile import load_profile  # noqa: E402

SETTINGS: tuple[tuple[str, str, float], ...] = (
    ("rain", "rate_mm_h", 1.0), ("rain", "rate_mm_h", 10.0), ("rain", "rate_mm_h", 25.0),
    ("rain", "rate_mm_h", 50.0), ("rain", "rate_mm_h", 100.0),
    ("snow", "rate_mm_h", 1.0), ("snow", "rate_mm_h", 5.0), ("snow", "rate_mm_h", 10.0),
    ("snow", "rate_mm_h", 20.0),
    ("fog", "visibility_m", 20.0), ("fog", "visibility_m", 50.0), ("fog", "visibility_m", 200.0),
    ("fog", "visibility_m", 1000.0),
    ("wet_ground", "water_film_mm", 0.5), ("wet_ground", "water_film_mm", 1.2),
)  # fmt: skip
# The other return modes at the targets' strengths (every mode must meet them).
MODE_SETTINGS: tuple[tuple[str, str, float, str], ...] = tuple(
    (name, key, value, mode)
    for name, key, value in (
        ("rain", "rate_mm_h", 25.0),
        ("snow", "rate_mm_h", 10.0),
        ("fog", "visibility_m", 50.0),
    )
    for mode in ("last", "dual")
)
TARGETS_MS = {
    ("rain", 25.0): 20.0, ("snow", 10.0): 20.0, ("fog", 50.0): 20.0, ("wet_ground", 1.2): 20.0,
}  # fmt: skip
REPEATS = 15


def _wet(labels: np.ndarray) -> Any:
    """lads.physics.wet_ground.wet_ground with the frame's labels bound, called like rain()."""

    def simulate(xyz: Any, intensity: Any, *, water_film_mm: float, **kw: Any) -> Any:
        return wet_ground(
            xyz, intensity, labels, "semantickitti", params=WetGroundParams(water_film_mm), **kw
        )

    return simulate


def _call(
    frames: list[np.ndarray], labels: list[np.ndarray], f_index: int, setting: tuple[Any, ...]
) -> Any:
    """One frame's simulation under one setting, as a function of the generator."""
    name, key, value, *rest = setting
    mode = rest[0] if rest else "strongest"
    profile = load_profile("hdl64e")
    simulate = _wet(labels[f_index]) if name == "wet_ground" else getattr(weather, name)
    points = frames[f_index]
    kw = {key: value} if name == "wet_ground" else {key: value, "mode": mode}
    return lambda rng: simulate(points[:, :3], points[:, 3], sensor=profile, rng=rng, **kw)


def _summary(
    setting: tuple[Any, ...],
    times_ms: list[float],
    faults: list[int],
    counts: list[dict[str, int]],
    n_points: int,
    n_frames: int,
) -> dict[str, Any]:
    """Median / min / p90 wall time per frame of one setting, its page faults and what it
    did."""
    name, key, value, *rest = setting
    arr = np.asarray(times_ms)
    summary: dict[str, Any] = {
        "weather": name,
        key: value,
        "mode": rest[0] if rest else "strongest",
        "median_ms_per_frame": round(float(np.median(arr)), 2),
        "min_ms": round(float(arr.min()), 2),
        "p90_ms": round(float(np.percentile(arr, 90)), 2),
        "runs": int(arr.size),
        # Minor page faults do not drift with the machine's speed, unlike wall time.
        "minor_page_faults_per_frame_median": int(np.median(faults)),
        "points_per_frame_mean": round(n_points / n_frames),
        "particle_fraction": round(sum(c["particle"] for c in counts) / n_points, 5),
        "lost_fraction": round(sum(c["lost"] for c in counts) / n_points, 5),
    }
    target = TARGETS_MS.get((name, value))
    if target is not None:
        summary["target_ms"] = target
        summary["meets_target"] = bool(summary["median_ms_per_frame"] <= target)
    return summary


def time_settings(
    frames: list[np.ndarray], labels: list[np.ndarray], settings: tuple[tuple[Any, ...], ...]
) -> list[dict[str, Any]]:
    """Every setting on every frame, REPEATS rounds, round-robin: a shared machine's slow
    spells then fall on all settings alike, so modes and weathers compare fairly."""
    calls = [[_call(frames, labels, f, s) for f in range(len(frames))] for s in settings]
    for per_setting in calls:  # warm-up: tables and numba caches built
        for call in per_setting:
            call(np.random.default_rng(0))
    times: list[list[float]] = [[] for _ in settings]
    faults: list[list[int]] = [[] for _ in settings]
    counts: list[list[dict[str, int]]] = [[{}] * len(frames) for _ in settings]
    for rep in tqdm(range(REPEATS), desc="speed rounds", unit="round"):
        for k, per_setting in enumerate(calls):
            for f, call in enumerate(per_setting):
                rng = np.random.default_rng([f, rep])
                faults_before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                start = time.perf_counter()
                result = call(rng)
                times[k].append(1e3 * (time.perf_counter() - start))
                faults[k].append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults_before)
                counts[k][f] = result.counts()
    n_points = sum(p.shape[0] for p in frames)
    return [
        _summary(s, times[k], faults[k], counts[k], n_points, len(frames))
        for k, s in enumerate(settings)
    ]


def page_fault_us(size_mb: int = 64, repeats: int = 5) -> float:
    """Microseconds per minor page fault on this machine: first touch of fresh anonymous
    pages, min over repeats (what an array the allocator maps anew costs per 4 kB)."""
    best = math.inf
    for _ in range(repeats):
        region = mmap.mmap(-1, size_mb << 20)
        view = np.frombuffer(region, dtype=np.uint8)
        start = time.perf_counter()
        view[:: mmap.PAGESIZE] = 1
        best = min(best, (time.perf_counter() - start) / ((size_mb << 20) // mmap.PAGESIZE))
        del view
        region.close()
    return round(best * 1e6, 3)


def main(out_dir: Path | None = None) -> dict[str, Any]:
    frames = kitti_frames()
    labels = kitti_labels()
    reference_workload = reference_workload_ms()
    rows = time_settings(frames, labels, SETTINGS + MODE_SETTINGS)
    payload = {
        "what": "wall time of lads.physics.weather.{rain,snow,fog} and "
        "lads.physics.wet_ground.wet_ground per real SemanticKITTI "
        "frame (sequence 00, frames 000000-000002), HDL-64E profile, strongest return "
        "unless `mode` says otherwise, "
        "one thread, after one warm-up call per frame (table and numba caches built), "
        "settings timed round-robin (each round runs every setting on every frame)",
        "machine": machine_info(),
        # The same fixed workloads before and after: how fast the machine was during the run.
        "reference_workload_before_after": [reference_workload, reference_workload_ms()],
        "page_fault_us": page_fault_us(),
        "results": rows,
    }
    write_result("speed.json", payload, out_dir)
    return payload


if __name__ == "__main__":
    for row in main()["results"]:
        key = next(k for k in ("rate_mm_h", "visibility_m", "water_film_mm") if k in row)
        print(
            f"{row['weather']:5s} {row[key]:7.1f} {row['mode']:9s} "  # noqa: T201
            f"median {row['median_ms_per_frame']:6.2f} ms"
        )
