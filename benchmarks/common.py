"""Shared helpers of the benchmarks: real-data paths, machine facts, atomic JSON output."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
from typing import Any

import numpy as np

from lads.errors import InputDataError

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
RESULTS = REPO / "benchmarks" / "results"
KITTI_SCANS = tuple(
    SHARED_DATA / "semantickitti" / "sequences" / "00" / "velodyne" / f"00000{i}.bin"
    for i in range(3)
)


def kitti_frames() -> list[np.ndarray]:
    """The three real SemanticKITTI scans as (N, 4) float32 arrays (read where they lie)."""
    missing = [str(p) for p in KITTI_SCANS if not p.is_file()]
    if missing:
        raise InputDataError(
            f"benchmark data missing: {missing}; the benchmarks read the real scans from "
            "../shared/data beside the checkout."
        )
    return [np.fromfile(p, dtype=np.float32).reshape(-1, 4) for p in KITTI_SCANS]


def kitti_labels() -> list[np.ndarray]:
    """The labels of the KITTI_SCANS, (N,) uint32 each, read by the SemanticKITTI reader."""
    from lads.readers import get_reader

    root = SHARED_DATA / "semantickitti"
    reader = get_reader("semantickitti", root)
    wanted = [p.relative_to(root).as_posix() for p in KITTI_SCANS]
    items = {item.relpath: item for item in reader.items()}
    missing = [w for w in wanted if w not in items]
    if missing:
        raise InputDataError(f"benchmark data missing under {root}: {missing}.")
    return [reader.read(items[w]).labels for w in wanted]


def machine_info() -> dict[str, Any]:
    import numba

    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
    }


def write_result(name: str, payload: dict[str, Any], out_dir: Path | None = None) -> Path:
    """Write benchmarks/results/<name> atomically."""
    folder = out_dir or RESULTS
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2) + "\n")
    tmp.replace(path)
    return path


def reference_workload_ms(repeats: int = 7) -> dict[str, float]:
    """Milliseconds of two fixed workloads on one core (min of `repeats`): a numpy one (sort
    and exp of 2M float64) and a torch one (a 3 x 3 convolution, 16 -> 16 channels, on a
    64 x 2048 map). This shared machine's speed drifts by 2x between sessions; reported
    beside each timing so results from different days can be compared."""
    import time

    import torch

    rng = np.random.default_rng(0)
    values = rng.random(2_000_000)
    conv = torch.nn.Conv2d(16, 16, 3, padding=1)
    image = torch.from_numpy(rng.random((1, 16, 64, 2048), dtype=np.float32))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)

    def best(fn: Any) -> float:
        fn()
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            fn()
            times.append((time.perf_counter() - start) * 1e3)
        return round(min(times), 2)

    try:
        with torch.inference_mode():
            return {
                "numpy_sort_exp_ms": best(lambda: (np.sort(values), np.exp(values))),
                "torch_conv_ms": best(lambda: conv(image)),
            }
    finally:
        torch.set_num_threads(threads)
