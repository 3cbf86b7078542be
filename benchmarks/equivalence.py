"""Fast path vs brute-force reference, measured in the same run: speed-up and equivalence.

Rain and snow: on the three real SemanticKITTI frames, the fast path runs FAST_SEEDS times
per frame and the brute force (every particle of every beam cone, tests/reference) once per
frame; the two-sample statistics of tests/realdata/test_equivalence.py are reported for every
weather and return mode. Speed-up = brute-force seconds per frame / fast seconds per frame,
both on the same frames, same machine, same process.

Fog: the brute force integrates each beam's waveform by adaptive quadrature (~10 ms per
beam, ~20 min per frame), so it is timed on FOG_BEAMS random beams of frame 000000 and
scaled to the frame's beam count; outcomes are compared beam by beam on those beams.

Run: .venv/bin/python -m benchmarks.equivalence   (writes benchmarks/results/equivalence.json)
"""

from __future__ import annotations

import os
from dataclasses import replace

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from benchmarks.common import kitti_frames, machine_info, write_result  # noqa: E402
from lads.physics.beams import auto_threshold, prepare_beams  # noqa: E402
from lads.physics.fog import (  # noqa: E402
    backscatter_from_visibility,
    extinction_from_visibility,
)
from lads.physics.result import Outcome  # noqa: E402
from lads.physics.weather import FOG_DEFAULTS, RAIN_DEFAULTS, fog  # noqa: E402
from lads.sensors.profile import load_profile  # noqa: E402
from tests.reference import fog_bruteforce as fb  # noqa: E402
from tests.reference.equivalence import (  # noqa: E402
    CASES,
    FAST_SEEDS,
    Sample,
    compare,
    fine_frame,
    fine_kitti_profile,
    run_brute,
    run_fast,
)

FOG_BEAMS = 300
FOG_VISIBILITY_M = 50.0


def particle_cases(frames: list[np.ndarray]) -> tuple[list[dict[str, Any]], Sample]:
    """One row per case, and the fast sample of the first case (for the power check)."""
    profile = fine_kitti_profile()
    rows = []
    first_fast: Sample | None = None
    for case in tqdm(CASES, desc="fast vs brute force", unit="case"):
        weather, rate, mode, detection = case
        fast, brute = Sample(), Sample()
        drawn = 0
        for i, points in enumerate(frames):
            xyz, intensity = fine_frame(points[:, :3], points[:, 3])
            run_fast(xyz, intensity, *case, 0, Sample(), profile)  # warm-up
            for seed in range(FAST_SEEDS):
                run_fast(xyz, intensity, *case, 1000 * i + seed, fast, profile)
            drawn += run_brute(xyz, intensity, *case, 7 + i, brute, profile)
        first_fast = first_fast or fast
        stats = compare(fast, brute)
        fast_s = fast.seconds / (FAST_SEEDS * len(frames))
        brute_s = brute.seconds / len(frames)
        rows.append(
            {
                "weather": weather,
                "rate_mm_h": rate,
                "mode": mode,
                "detection": detection,
                "frames": len(frames),
                "fast_runs": FAST_SEEDS * len(frames),
                "brute_runs": len(frames),
                "brute_particles_drawn_per_frame": round(drawn / len(frames)),
                "fast_ms_per_frame": round(1e3 * fast_s, 2),
                "brute_s_per_frame": round(brute_s, 3),
                "speed_up": round(brute_s / fast_s, 1),
                **_rounded(stats),
            }
        )
    return rows, first_fast or Sample()


def power_check(frames: list[np.ndarray], fast: Sample) -> dict[str, Any]:
    """The same statistics against a wrong brute force (rho_p doubled) must reject it."""
    case = CASES[0]
    wrong = Sample()
    rho_p = RAIN_DEFAULTS.particle_reflectivity
    for i, points in enumerate(frames):
        xyz, intensity = fine_frame(points[:, :3], points[:, 3])
        run_brute(
            xyz,
            intensity,
            *case,
            99 + i,
            wrong,
            fine_kitti_profile(),
            particle_reflectivity=2 * rho_p,
        )
    return {
        "case": " ".join(map(str, case)) + ", brute force with particle_reflectivity x 2",
        **_rounded(compare(fast, wrong)),
    }


def fog_case(points: np.ndarray) -> dict[str, Any]:
    profile = load_profile("hdl64e")
    xyz, intensity = points[:, :3], points[:, 3]
    params = FOG_DEFAULTS.resolved_for(profile)
    beams = prepare_beams(xyz, intensity, profile)
    chosen = np.sort(np.random.default_rng(11).choice(len(xyz), FOG_BEAMS, replace=False))
    alpha = extinction_from_visibility(FOG_VISIBILITY_M)
    beta = backscatter_from_visibility(FOG_VISIBILITY_M, params)
    constants = fb.FogConstants.from_params(alpha, beta, params)
    start = time.perf_counter()
    brute = fb.simulate_beams(
        beams.range_m[chosen], beams.reflectivity[chosen], constants, auto_threshold(beams)
    )
    brute_s_per_beam = (time.perf_counter() - start) / FOG_BEAMS
    # Beam by beam needs a deterministic rule: the frame-calibrated hard threshold.
    hard = replace(FOG_DEFAULTS, detection_threshold="frame")
    fog(
        xyz,
        intensity,
        visibility_m=FOG_VISIBILITY_M,
        sensor=profile,
        params=hard,
        rng=np.random.default_rng(0),
    )
    times = []
    for seed in range(FAST_SEEDS):
        start = time.perf_counter()
        result = fog(
            xyz,
            intensity,
            visibility_m=FOG_VISIBILITY_M,
            sensor=profile,
            params=hard,
            rng=np.random.default_rng(seed),
        )
        times.append(time.perf_counter() - start)
    fast = np.full(len(xyz), Outcome.LOST, dtype=np.uint8)
    fast[result.source_index] = result.outcome
    fast_s = float(np.median(times))
    brute_frame_s = brute_s_per_beam * len(xyz)
    return {
        "weather": "fog",
        "visibility_m": FOG_VISIBILITY_M,
        "mode": "strongest",
        "beams_compared": FOG_BEAMS,
        "outcome_agreement": float(np.mean(fast[chosen] == brute["strongest"])),
        "fast_ms_per_frame": round(1e3 * fast_s, 2),
        "brute_s_per_frame_extrapolated": round(brute_frame_s, 1),
        "speed_up": round(brute_frame_s / fast_s, 1),
    }


def _rounded(stats: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in stats.items():
        if isinstance(value, dict):
            out[key] = {k: float(f"{v:.4g}") for k, v in value.items()}
        else:
            out[key] = float(f"{value:.4g}")
    return out


def main(out_dir: Path | None = None) -> dict[str, Any]:
    frames = kitti_frames()
    rows, first_fast = particle_cases(frames)
    payload = {
        "what": "lads fast weather paths vs the brute-force references in tests/reference, "
        "on real SemanticKITTI 00/000000-000002, same process and machine; statistics as in "
        "tests/realdata/test_equivalence.py (two-proportion z-test p and Cohen's h for lost "
        "and particle fractions, KS p for particle-return range and intensity)",
        "machine": machine_info(),
        "particles": rows,
        "power_check": power_check(frames, first_fast),
        "fog": fog_case(frames[0]),
    }
    write_result("equivalence.json", payload, out_dir)
    return payload


if __name__ == "__main__":
    main()
