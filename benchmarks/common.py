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
