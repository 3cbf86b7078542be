"""`make bench`: every benchmark, each writing its JSON under benchmarks/results/.

speed.json        ms per real SemanticKITTI frame per weather and rate (one core)
equivalence.json  fast path vs the brute-force reference: speed-up and two-sample tests
anchors.json      rain extinction vs Ulbrich-Atlas, Q_ext, incidence on a real frame
wads_snow.json    simulated vs real falling snow (WADS), fitted defaults vs LISA settings
detection_limit.json  sensor detection limits measured on real clear frames (HDL-32E)
fog_radiate.json  fog model vs real fog (RADIATE), with what that data cannot show
realism.json      each weather and severity on real KITTI frames beside WADS snow and RADIATE fog
build_speed.json  lads build end to end: frames/s with 1 and 2 jobs, memory, projected hours
verify.json       lads verify throughput (MB/s) on a ~450 MB tree
intensity_speed.json  intensity generator ms per 64-beam frame on one core
intensity_eval.json   held-out evaluation of the shipped generators against the baselines
diagnose_real.json    lads diagnose: a simple rho cos/R^2 simulator vs real KITTI and nuScenes
faults.json           fault injection: kills, races, damage, bad frames, full/read-only disks
sensor_transfer.json  sensor transfer vs the target's direct render (ground truth), speed
sensor_transfer_real.json  sensor transfer of real scans, ring statistics vs real target scans
sensor_build_speed.json    lads build --variant sensor-hdl32e: frames/s, memory, Dask bytes
augment_speed.json    lads.augment corruptions through each loader adapter: frames/s, one core
ground_fit.json       the ground fit (wet ground without labels) against labelled real frames
variant_sweep.json    every other shipped variant built and verified on real frames by `lads`
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import importlib  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

from tqdm import tqdm  # noqa: E402

BENCHMARKS = (
    "speed",
    "equivalence",
    "anchors",
    "wads_snow",
    "detection_limit",
    "fog_radiate",
    "realism",
    "build_speed",
    "verify_speed",
    "intensity_speed",
    "intensity_eval",
    "diagnose_real",
    "faults",
    "sensor_transfer",
    "sensor_transfer_real",
    "sensor_build_speed",
    "augment_speed",
    "ground_fit",
    "variant_sweep",
)


def main() -> int:
    timings = {}
    for name in tqdm(BENCHMARKS, desc="benchmarks", unit="bench"):
        start = time.perf_counter()
        importlib.import_module(f"benchmarks.{name}").main()
        timings[name] = round(time.perf_counter() - start, 1)
    sys.stdout.write(f"benchmarks done (seconds: {timings}); results in benchmarks/results/\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
