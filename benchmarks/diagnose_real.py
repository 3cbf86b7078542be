"""The real case M3 of `lads diagnose` (docs/diagnose.md §6.2): a simple simulator vs reality.

    .venv/bin/python -m benchmarks.diagnose_real [--bases semantickitti,nuscenes]
                                                 [--resamples N] [--bootstrap N]

No effect is planted. For each base the simulated tree holds the real geometry, row order and
labels with the simple simulator's intensity

    I_sim = c * rho * cos(theta) / R^2

rho = `reflectance_for_labels(labels, "semantickitti")` (nuScenes is unlabelled: rho = 0.2),
cos(theta) = `incidence_cos(xyz, profile, channel=ring)` (KITTI rings from the scan order,
nuScenes from the ring column), points at zero range kept with intensity 0, c one constant per
base that puts the median of I_sim at the real median, then quantised to the sensor's encoding
(KITTI: 0.01 steps in [0, 0.99]; nuScenes: integers in [0, 255]). The real tree is
../shared/data/<base> itself. `lads diagnose --paired --seed 0` runs as a subprocess exactly as
a user would run it; its report and figures go to benchmarks/results/diagnose_real/<base>/ and
a summary of both to benchmarks/results/diagnose_real.json.

Bases: "semantickitti" (3 labelled HDL-64E frames of sequence 00) and "nuscenes" (one
unlabelled HDL-32E LIDAR_TOP keyframe, 5 float32 columns x, y, z, intensity, ring).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from benchmarks.common import RESULTS, SHARED_DATA, machine_info, write_result
from lads.physics.materials import reflectance_for_labels
from lads.physics.modalities import incidence_cos
from lads.sensors.measure import rings_from_scan_order
from lads.sensors.profile import SensorProfile, load_profile

BASES = ("semantickitti", "nuscenes")
REAL_ROOTS = {"semantickitti": SHARED_DATA / "semantickitti", "nuscenes": SHARED_DATA / "nuscenes"}
PROFILES = {"semantickitti": "hdl64e", "nuscenes": "hdl32e"}
KITTI_SCANS = ("000000", "000001", "000002")
UNLABELLED_RHO = 0.2
SEED = 0
# Effort of the diagnosis: the tool's own defaults (lads.diagnose.verdict.analysis.Settings), so the
# time recorded here is the time a user waits for `lads diagnose` on these frames.
RESAMPLES = 10
BOOTSTRAP = 40
TOOL_TIMEOUT_S = 1800
TOP_STATEMENTS = 5
OUT_DIR = RESULTS / "diagnose_real"


def simple_intensity(
    xyz: npt.NDArray[np.float64],
    rho: npt.NDArray[np.float64],
    ring: npt.NDArray[np.int64],
    profile: SensorProfile,
) -> npt.NDArray[np.float64]:
    """Unscaled rho cos(theta) / R^2 (0 at zero range), (N,) float64."""
    r = np.sqrt(np.einsum("ij,ij->i", xyz, xyz))
    cos = incidence_cos(xyz, profile, channel=ring).astype(np.float64)
    out = np.zeros(len(xyz))
    ok = r > 0.0
    out[ok] = rho[ok] * cos[ok] / r[ok] ** 2
    return out


def _quantise(x: npt.NDArray[np.float64], profile: SensorProfile) -> npt.NDArray[np.float32]:
    enc = profile.intensity
    return enc.from_reflectivity(np.clip(x, 0.0, None) / enc.reflectivity_full_scale)


def build_sim(base: str, sim_root: Path) -> dict[str, Any]:
    """Write the simulated tree of `base` under `sim_root`; returns what was written."""
    profile = load_profile(PROFILES[base])
    real_root = REAL_ROOTS[base]
    scans: list[dict[str, Any]] = []
    if base == "semantickitti":
        for name in KITTI_SCANS:
            rel = f"sequences/00/velodyne/{name}.bin"
            lab_rel = f"sequences/00/labels/{name}.label"
            pts = np.fromfile(real_root / rel, dtype="<f4").reshape(-1, 4)
            labels = np.fromfile(real_root / lab_rel, dtype="<u4")
            xyz = pts[:, :3].astype(np.float64)
            ring = rings_from_scan_order(xyz, profile.channels)
            rho = reflectance_for_labels(labels, "semantickitti").astype(np.float64)
            scans.append(
                {"rel": rel, "label_rel": lab_rel, "pts": pts, "xyz": xyz, "ring": ring, "rho": rho}
            )
    else:
        for path in sorted((real_root / "samples" / "LIDAR_TOP").glob("*.pcd.bin")):
            pts = np.fromfile(path, dtype="<f4").reshape(-1, 5)
            xyz = pts[:, :3].astype(np.float64)
            scans.append(
                {
                    "rel": path.relative_to(real_root).as_posix(),
                    "label_rel": None,
                    "pts": pts,
                    "xyz": xyz,
                    "ring": pts[:, 4].astype(np.int64),
                    "rho": np.full(len(pts), UNLABELLED_RHO),
                }
            )
    if not scans:
        raise FileNotFoundError(f"no {base} scans under {real_root}")
    raw = [simple_intensity(s["xyz"], s["rho"], s["ring"], profile) for s in scans]
    r = np.concatenate([np.linalg.norm(s["xyz"], axis=1) for s in scans])
    valid = r > 0.0
    near = int(np.count_nonzero(r < 1.0))
    real_i = np.concatenate([s["pts"][:, 3] for s in scans]).astype(np.float64)
    real_median = float(np.median(real_i[valid]))
    sim_median_raw = float(np.median(np.concatenate(raw)[valid]))
    scale = real_median / sim_median_raw
    points = 0
    saturated = 0
    for s, x in zip(scans, raw, strict=True):
        stored = _quantise(scale * x, profile)
        pts = s["pts"].copy()
        pts[:, 3] = stored
        path = sim_root / s["rel"]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(np.ascontiguousarray(pts, dtype="<f4").tobytes())
        if s["label_rel"] is not None:
            lab = sim_root / s["label_rel"]
            lab.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(REAL_ROOTS[base] / s["label_rel"], lab)
        points += len(pts)
        saturated += int(np.count_nonzero(stored >= profile.intensity.max_value))
    sim_stored = np.concatenate(
        [np.fromfile(sim_root / s["rel"], dtype="<f4").reshape(s["pts"].shape)[:, 3] for s in scans]
    )
    return {
        "frames": len(scans),
        "scans": [s["rel"] for s in scans],
        "points": points,
        "profile": profile.name,
        "scale": scale,
        "real_median": real_median,
        "sim_median_stored": float(np.median(sim_stored[valid])),
        "sim_saturated_fraction": saturated / points,
        "sim_zero_fraction": float(np.mean(sim_stored == 0.0)),
        "real_zero_fraction": float(np.mean(real_i == 0.0)),
        # nuScenes stores ego-body and invalid returns at 0-1 m; the tool keeps them.
        "points_below_1m": near,
    }


def run_tool(base: str, sim_root: Path, out: Path, resamples: int, bootstrap: int) -> float:
    """Run `lads diagnose` on (sim_root, the real tree); returns its wall time in s."""
    cmd = [
        sys.executable,
        "-m",
        "lads.cli",
        "diagnose",
        "--sim",
        str(sim_root),
        "--real",
        str(REAL_ROOTS[base]),
        "--source",
        base,
        "--paired",
        "--out",
        str(out),
        "--seed",
        str(SEED),
        "--resamples",
        str(resamples),
        "--bootstrap",
        str(bootstrap),
    ]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TOOL_TIMEOUT_S)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(
            f"lads diagnose on {base} failed (exit {proc.returncode}): {proc.stderr[-3000:]}"
        )
    sys.stdout.write(proc.stdout.strip().splitlines()[-1] + "\n" if proc.stdout.strip() else "")
    return wall


def summarise(report: dict[str, Any]) -> dict[str, Any]:
    """The parts of report.json the summary keeps."""
    return {
        "verdict": report["verdict"],
        "verdict_reasons": report["verdict_reasons"],
        "rows": report["rows"],
        "scans": report["scans"],
        # report.json's "baseline" holds the C0 gain of the final model (with the effects).
        "final_ln_gain_c0": report["baseline"]["ln_gain_with_effects"],
        "effects": [
            {
                k: e[k]
                for k in ("id", "key", "name", "params", "ci95", "selection_frequency", "status")
                if k in e
            }
            | ({"classes": e["classes"]} if "classes" in e else {})
            for e in report["effects"]
        ],
        "possible_effects": report["possible_effects"],
        "alternatives": report["alternatives"],
        "ambiguity_sets": report["ambiguity_sets"],
        "noise_model": report["noise_model"],
        "heldout": report["heldout"],
        "split": report["split"],
        "localization_before": [s.get("text") for s in report["localization"][:TOP_STATEMENTS]],
        "localization_after": [
            s.get("text") for s in report.get("localization_after", [])[:TOP_STATEMENTS]
        ],
        "figures": [f"diagnose_real/{report['source']}/{f}" for f in report["figures"]],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bases", default=",".join(BASES))
    ap.add_argument("--resamples", type=int, default=RESAMPLES)
    ap.add_argument("--bootstrap", type=int, default=BOOTSTRAP)
    args = ap.parse_args(argv)
    bases = [b for b in args.bases.split(",") if b]
    unknown = set(bases) - set(BASES)
    if unknown:
        ap.error(f"unknown bases {sorted(unknown)}; expected some of {BASES}")
    start = time.perf_counter()
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="lads-diagnose-real-") as tmp:
        for base in bases:
            t0 = time.perf_counter()
            sim_root = Path(tmp) / base
            sim = build_sim(base, sim_root)
            t_build = time.perf_counter() - t0
            out = OUT_DIR / base
            if out.exists():
                shutil.rmtree(out)
            t_tool = run_tool(base, sim_root, out, args.resamples, args.bootstrap)
            report = json.loads((out / "report.json").read_text())
            results[base] = {
                "base": base,
                "real_root": f"../shared/data/{base}",
                "report": f"benchmarks/results/diagnose_real/{base}/report.md",
                **sim,
                "wall_s": {"build_sim": round(t_build, 1), "diagnose": round(t_tool, 1)},
                **summarise(report),
            }
    payload = {
        "benchmark": "diagnose_real (docs/diagnose.md §6.2 M3): simple simulator vs real data",
        "simulator": "I = c * rho * cos(theta) / R^2 on the real geometry, quantised",
        "command": ".venv/bin/python -m benchmarks.diagnose_real",
        "tool_args": {
            "paired": True,
            "seed": SEED,
            "resamples": args.resamples,
            "bootstrap": args.bootstrap,
        },
        "wall_s": round(time.perf_counter() - start, 1),
        "machine": machine_info(),
        "bases": results,
    }
    path = write_result("diagnose_real.json", payload)
    sys.stdout.write(f"diagnose_real: {payload['wall_s']} s; wrote {path}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
