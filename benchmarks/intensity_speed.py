"""Intensity generator inference speed on one CPU core -> intensity_speed.json.

Times, on the real SemanticKITTI frames (64 x 2048 range image, ~124k points), with
torch.set_num_threads(1):
- network: the shipped synth-to-kitti generator's forward pass on the prepared inputs (the
  range image for a U-Net, every point's inputs and law for a pointwise generator);
- features: projection, incidence, materials and I_P (numpy, `frame_image`);
- incidence: the part of features spent on incidence (range-image normals, kNN fallback);
- fallback: of that, the k-nearest-neighbour PCA normals of the points without a usable
  normal of their own pixel (direction grid, neighbour search and plane fits,
  `lads.physics.sphere_knn`; `fallback_points` of them); plane_fit: of that, the plane fits
  alone (`lads.physics.knn_normals`, closed-form eigenproblem);
- frame: all of `predict_points` (scan check + features + network + every point's value +
  encoding);
- snow_stage: the default snow variant's learned stage (the weather model, width 32) as a
  build runs it, on the same frames after its snow stage (seed 0), `stage_ms` per frame.
Budget: <= 35 ms per 64-beam frame on one core for the whole stage (`frame` and
`snow_stage`, medians over the frames), features and per-point values included, not only the
network.
"""

from __future__ import annotations

import statistics
import sys
import time
from typing import Any

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from benchmarks.common import machine_info, reference_workload_ms, write_result
from lads.config import pipeline_for
from lads.intensity.checkpoint import resolve_model
from lads.intensity.features import frame_image
from lads.intensity.predict import predict_image, predict_points
from lads.physics.knn_normals import _plane_cos
from lads.physics.modalities import (
    DEFAULT_MAX_DEPTH_JUMP,
    KNN_MIN_NEIGHBOURS,
    KNN_MIN_PLANARITY,
    KNN_NEIGHBOURS,
    KNN_RADIUS_M,
    IncidenceSource,
    _incidence,
    _neighbour_cos,
)
from lads.physics.projection import channels_of, checked_xyz, organise
from lads.physics.sphere_knn import knn_within
from lads.readers import get_reader
from lads.seeding import rng_for
from lads.sensors.profile import load_profile
from lads.stages import build_stages

TARGET_MS = 35.0
REPEATS = 9  # median of; the machine is shared
KITTI_ROOT = "../shared/data/semantickitti"


def _median_ms(fn: Any) -> float:
    fn()  # warm-up
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1e3)
    return round(statistics.median(times), 1)


def _network(model: Any, fi: Any) -> Any:
    """The generator's own forward pass on one prepared frame."""
    if model.meta.architecture != "pointwise":
        return predict_image(model, fi)
    n = fi.point_inputs.shape[1]
    raw = torch.from_numpy(fi.point_inputs)[None, :, :, None]
    law = torch.zeros((1, 1, n, 1), dtype=torch.float32)
    with torch.inference_mode():  # every point occupied: no mask, as the stage runs it
        return model.generator.infer(raw, None, law)


def _incidence_only(xyz: np.ndarray, profile: Any) -> None:
    xyz64, r = checked_xyz(xyz)
    image = organise(
        xyz64, r, channels_of(xyz64, profile, None), profile.channels, profile.range_image_width
    )
    _incidence(xyz64, r, image, DEFAULT_MAX_DEPTH_JUMP)


def _fallback_points(xyz: np.ndarray, profile: Any) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float64 points and the indices of those the neighbour fallback answers."""
    xyz64, r = checked_xyz(xyz)
    image = organise(
        xyz64, r, channels_of(xyz64, profile, None), profile.channels, profile.range_image_width
    )
    source = _incidence(xyz64, r, image, DEFAULT_MAX_DEPTH_JUMP).source
    return xyz64, np.flatnonzero(source != IncidenceSource.IMAGE)


def _plane_fits(xyz64: np.ndarray, rest: np.ndarray) -> Any:
    """The fallback's plane fits alone, on neighbours found once."""
    query = rest.astype(np.int64)
    idx, _ = knn_within(xyz64, query, k=KNN_NEIGHBOURS, radius_m=KNN_RADIUS_M)
    return lambda: _plane_cos(xyz64, query, idx, KNN_MIN_NEIGHBOURS, KNN_MIN_PLANARITY)


def main() -> dict[str, Any]:
    # One core: torch and every OpenMP / BLAS pool (pykdtree, the incidence fallback's tree
    # for the scans its grid does not suit, is OpenMP-parallel) limited to one thread.
    torch.set_num_threads(1)
    with threadpool_limits(limits=1):
        return _measure()


def _measure() -> dict[str, Any]:
    model = resolve_model("synth-to-kitti")
    profile = load_profile("hdl64e")
    reader = get_reader("semantickitti", KITTI_ROOT)
    rows = []
    for item in reader.items():
        frame = reader.read(item)
        fi = frame_image(
            frame.xyz,
            profile,
            labels=frame.labels,
            label_set="semantickitti",
            range_exponent=model.meta.range_exponent,
        )
        xyz64, rest = _fallback_points(frame.xyz, profile)
        rows.append(
            {
                "frame": item.relpath,
                "points": int(len(frame.xyz)),
                "image": list(fi.inputs.shape[1:]),
                "network_ms": _median_ms(lambda fi=fi: _network(model, fi)),
                "features_ms": _median_ms(
                    lambda f=frame: frame_image(
                        f.xyz, profile, labels=f.labels, label_set="semantickitti"
                    )
                ),
                "incidence_ms": _median_ms(lambda f=frame: _incidence_only(f.xyz, profile)),
                "fallback_points": int(rest.size),
                "fallback_ms": _median_ms(lambda x=xyz64, q=rest: _neighbour_cos(x, q)),
                "plane_fit_ms": _median_ms(_plane_fits(xyz64, rest)),
                "frame_ms": _median_ms(
                    lambda f=frame: predict_points(
                        model, f.xyz, profile, labels=f.labels, label_set="semantickitti"
                    )
                ),
            }
        )
    network = float(np.median([r["network_ms"] for r in rows]))
    result = {
        "what": "synth-to-kitti generator on real SemanticKITTI frames, torch 1 thread",
        "architecture": model.meta.architecture,
        "parameters": sum(p.numel() for p in model.generator.parameters()),
        "frames": rows,
        "network_ms_median": network,
        "features_ms_median": float(np.median([r["features_ms"] for r in rows])),
        "incidence_ms_median": float(np.median([r["incidence_ms"] for r in rows])),
        "fallback_ms_median": float(np.median([r["fallback_ms"] for r in rows])),
        "plane_fit_ms_median": float(np.median([r["plane_fit_ms"] for r in rows])),
        "frame_ms_median": float(np.median([r["frame_ms"] for r in rows])),
        "target_frame_ms": TARGET_MS,
        "meets_target": float(np.median([r["frame_ms"] for r in rows])) <= TARGET_MS,
        "machine": machine_info(),
        "reference_workload": reference_workload_ms(),
    }
    result["snow_stage"] = _snow_stage()
    path = write_result("intensity_speed.json", result)
    sys.stdout.write(
        f"intensity: network {network} ms, whole frame {result['frame_ms_median']} ms per "
        f"64-beam frame on one core (snow's learned stage "
        f"{result['snow_stage']['stage_ms_median']} ms) -> {path}\n"
    )
    return result


def _snow_stage() -> dict[str, Any]:
    """The default snow variant's learned stage, per frame after its snow stage."""
    pipeline = pipeline_for("semantickitti", "snow")
    weather, learned = build_stages(pipeline)
    reader = get_reader("semantickitti", KITTI_ROOT)
    rows = []
    for item in reader.items():
        rng = rng_for(0, item.item_id, pipeline.variant, weather.name)
        frame = weather(reader.read(item), rng)
        rows.append(
            {
                "frame": item.relpath,
                "points": int(len(frame.xyz)),
                "stage_ms": _median_ms(lambda f=frame: learned(f, np.random.default_rng(0))),
            }
        )
    median = float(np.median([r["stage_ms"] for r in rows]))
    return {
        "stages": [weather.name, learned.name],
        "frames": rows,
        "stage_ms_median": median,
        "target_ms": TARGET_MS,
        "meets_target": median <= TARGET_MS,
    }


if __name__ == "__main__":
    main()
