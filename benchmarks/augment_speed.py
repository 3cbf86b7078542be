"""Frames per second of every lads.augment corruption inside a data loader, on one core.

Each real SemanticKITTI frame (~120k points) goes through each adapter with its labels and
instance ids, so the time includes the conversion to and from tensors and the re-indexing of
both label arrays: the PyTorch Dataset wrapper, the mmdetection3d transform (on a results
dict whose points are a tensor), the OpenPCDet DataAugmentor entry, and the bare
`Corruption` call. Target: >= 40 frames/s per core for the physics weather (issue 31).

Run: .venv/bin/python -m benchmarks.augment_speed   (writes benchmarks/results/augment_speed.json)
"""

from __future__ import annotations

import os

# One core, as the target says: pin every thread pool before numpy/numba/torch load.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from tqdm import tqdm  # noqa: E402

from benchmarks.common import (  # noqa: E402
    kitti_frames,
    kitti_labels,
    machine_info,
    reference_workload_ms,
    write_result,
)
from lads.augment import CORRUPTIONS, SEVERITIES, Corruption  # noqa: E402
from lads.augment.mmdet3d import LadsCorruption  # noqa: E402
from lads.augment.openpcdet import OpenPCDetCorruption  # noqa: E402
from lads.augment.torch_data import CorruptedDataset  # noqa: E402
from lads.physics.result import Outcome  # noqa: E402

REPEATS = 10
TARGET_FPS = 40.0
# The target applies to the physics weather; the sensor faults are reported beside it.
WEATHER = ("fog", "rain", "snow", "wet_ground")
# Cross-sensor has no severities: the KITTI frames go to the HDL-32E.
CROSS_SENSOR_TARGET = "hdl32e"


class _Samples(torch.utils.data.Dataset):  # type: ignore[type-arg]
    def __init__(self, points: list[np.ndarray], labels: list[np.ndarray]) -> None:
        self.samples = [
            {
                "points": torch.from_numpy(p),
                "labels": torch.from_numpy((lab & 0xFFFF).astype(np.int64)),
                "instance": torch.from_numpy((lab >> 16).astype(np.int64)),
                "path": f"00/{i:06d}",
            }
            for i, (p, lab) in enumerate(zip(points, labels, strict=True))
        ]

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, i: int) -> dict[str, Any]:
        return self.samples[i]


def _paths(
    name: str, severity: str | None, points: list[np.ndarray], labels: list[np.ndarray]
) -> dict[str, Callable[[int], Any]]:
    """One callable per adapter: frame index -> corrupted sample."""
    options: dict[str, Any] = {"sensor": "hdl64e", "dataset": "semantickitti", "seed": 0}
    params = {} if CORRUPTIONS[name].has_presets else {"target": CROSS_SENSOR_TARGET}
    core = Corruption(name, severity, **options, **params)
    wrapped = CorruptedDataset(
        _Samples(points, labels),
        core,
        labels_key="labels",
        instance_key="instance",
        id_key="path",
    )
    mmdet = LadsCorruption(name, severity=severity, **options, **params)
    pcdet = OpenPCDetCorruption(
        {
            "NAME": "lads_corruption",
            "CORRUPTION": name,
            "SEVERITY": severity,
            "SENSOR": "hdl64e",
            "DATASET": "semantickitti",
            "PARAMS": params,
        }
    )
    semantic = [(lab & 0xFFFF).astype(np.int64) for lab in labels]
    instance = [(lab >> 16).astype(np.int64) for lab in labels]

    def mmdet_call(i: int) -> Any:
        results = {
            "points": torch.from_numpy(points[i]),
            "pts_semantic_mask": semantic[i],
            "pts_instance_mask": instance[i],
            "sample_idx": i,
        }
        return mmdet.transform(results)

    paths = {
        "core": lambda i: core(points[i], semantic[i], instance[i], sample_id=i),
        "torch_dataset": wrapped.__getitem__,
        "mmdet3d": mmdet_call,
        "openpcdet": lambda i: pcdet({"points": points[i], "frame_id": f"{i:06d}"}),
    }
    if name == "incomplete_echo":  # it finds vehicles by gt_boxes, which these frames lack
        del paths["openpcdet"]
    return paths


def _effect(call: Callable[[int], Any], points: list[np.ndarray]) -> dict[str, float]:
    """Per input point, pooled over the frames: output points, lost input points, and output
    points that are particle (or false) returns, displaced or attenuated."""
    total = sum(p.shape[0] for p in points)
    lost = particle = displaced = attenuated = output = 0
    for i in range(len(points)):
        info = call(i).info
        output += info.outcome.size
        lost += info.lost_index.size
        particle += int(np.count_nonzero(info.outcome == Outcome.PARTICLE))
        displaced += int(np.count_nonzero(info.outcome == Outcome.DISPLACED))
        attenuated += int(np.count_nonzero(info.outcome == Outcome.ATTENUATED))
    shares = {
        "output": output,
        "lost": lost,
        "particle": particle,
        "displaced": displaced,
        "attenuated": attenuated,
    }
    return {k: round(v / total, 5) for k, v in shares.items()}


def _times_ms(paths: dict[str, Callable[[int], Any]], frames: int) -> dict[str, list[float]]:
    """Milliseconds of every call, per adapter. The adapters take turns frame by frame, so a
    burst of load from another process on this shared machine hits them all alike."""
    for call in paths.values():
        call(0)  # compile and warm caches outside the timing
    times: dict[str, list[float]] = {name: [] for name in paths}
    for _ in range(REPEATS):
        for i in range(frames):
            for name, call in paths.items():
                start = time.perf_counter()
                call(i)
                times[name].append((time.perf_counter() - start) * 1000.0)
    return times


def main() -> None:
    torch.set_num_threads(1)
    points, labels = kitti_frames(), kitti_labels()
    rows = []
    cases: list[tuple[str, str | None]] = [
        (n, s) for n, spec in CORRUPTIONS.items() if spec.has_presets for s in SEVERITIES
    ]
    cases += [(n, None) for n, spec in CORRUPTIONS.items() if not spec.has_presets]
    effects = []
    for name, severity in tqdm(cases, desc="augment speed", unit="case"):
        paths = _paths(name, severity, points, labels)
        effects.append({"corruption": name, "severity": severity, **_effect(paths["core"], points)})
        for adapter, times in _times_ms(paths, len(points)).items():
            ms = statistics.median(times)
            rows.append(
                {
                    "corruption": name,
                    "severity": severity,
                    "adapter": adapter,
                    "median_ms": round(ms, 2),
                    "min_ms": round(min(times), 2),
                    "frames_per_s": round(1000.0 / ms, 1),
                }
            )
    weather = [r for r in rows if r["corruption"] in WEATHER]
    slowest = min(weather, key=lambda r: r["frames_per_s"])
    payload = {
        "what": "median ms per real SemanticKITTI frame through each lads.augment adapter, "
        "labels and instance ids re-indexed, one core",
        "frames": [int(p.shape[0]) for p in points],
        "repeats": REPEATS,
        "target_frames_per_s": TARGET_FPS,
        "slowest_weather": slowest,
        "weather_target_met": bool(slowest["frames_per_s"] >= TARGET_FPS),
        "rows": rows,
        "effect_what": "per input point, pooled over the frames: output points, lost input "
        "points, and output points per outcome (particle, displaced, attenuated)",
        "effects": effects,
        "machine": machine_info(),
        # The machine's speed during the run (fixed numpy and torch workloads, one core).
        "reference_workload_ms": reference_workload_ms(),
    }
    write_result("augment_speed.json", payload)


if __name__ == "__main__":
    main()
