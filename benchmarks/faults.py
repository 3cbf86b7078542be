"""The fault-injection campaign of `lads build` -> benchmarks/results/faults.json.

    python -m benchmarks.faults                  # real SemanticKITTI frames, snow, every fault
    python -m benchmarks.faults --source synth --variant rain --kills 4 --races 2

Classes (benchmarks/fault_cases.py, fault_processes.py): unreadable or corrupt source
frames (`bad_entry`), damage to a finished tree that a rerun must repair (`damage`), the
output folder or disk saying no (`error`), SIGKILL / SIGINT at random moments including
finalise, once and twice (`kill`), and builds racing for one output (`concurrent`). Each row
records tried / caught / survived / lost; "lost" is anything short of a tree that verifies
and equals the uninterrupted build after the user's remedy.
"""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import fault_cases as fc
from benchmarks import fault_processes as fp
from benchmarks.common import SHARED_DATA, machine_info, write_result

KITTI = {"00": ("000000", "000001", "000002", "000052", "000088", "000850", "004501"),
         "90": ("000000", "000001", "000002", "000003", "000019")}  # fmt: skip


def real_source(root: Path) -> Path:
    """The 12 labelled real SemanticKITTI frames, symlinked (never copied) into `root`."""
    roots = {"000052": "semantickitti-more", "000088": "semantickitti-more",
             "000850": "semantickitti-more", "004501": "semantickitti-more"}  # fmt: skip
    for seq, stems in KITTI.items():
        for stem in stems:
            base = "semantickitti-seqx" if seq == "90" else roots.get(stem, "semantickitti")
            src = SHARED_DATA / base / "sequences" / seq
            for sub, ext in (("velodyne", "bin"), ("labels", "label")):
                link = root / "sequences" / seq / sub / f"{stem}.{ext}"
                link.parent.mkdir(parents=True, exist_ok=True)
                link.symlink_to(src / sub / f"{stem}.{ext}")
    for name in ("calib.txt", "times.txt"):
        (root / "sequences" / "00" / name).symlink_to(
            SHARED_DATA / "semantickitti" / "sequences" / "00" / name
        )
    return root


def synth_source(root: Path, frames: int = 6) -> Path:
    from lads.synth import write_synthetic_dataset

    write_synthetic_dataset(root, frames=frames, seed=3, azimuth_bins=512)
    return root


def run_campaign(bench: fc.Bench, kills: int, races: int, seed: int = 0) -> list[fc.Result]:
    """Every fault of every class against `bench`; `kills` random kill moments (each also
    run as SIGINT and as a double kill on a third of them) and `races` of each race kind."""
    results = [fc.bad_entry(bench, k) for k in fc.ENTRY_KINDS + fc.POINT_KINDS]
    results += [fc.damage(bench, k) for k in fc.DAMAGE]
    results += [fc.foreign_file(bench), fc.source_changed(bench)]
    results += [fc.run_json(bench, k) for k in ("run_json_not_json", "run_json_foreign")]
    results += [fp.disk_full(bench), fp.read_only(bench)]
    rng = np.random.default_rng(seed)
    if kills:
        total = fp.timed_reference(bench)
        items = len(fc.listed_items(bench))
        for i, (trigger, delay) in enumerate(fp.kill_moments(total, items, kills, rng)):
            results.append(fp.kill(bench, trigger, delay_s=delay))
            if i % 3 == 0:
                results.append(fp.kill(bench, trigger, signal.SIGINT, delay_s=delay))
                results.append(fp.kill(bench, trigger, twice=True, delay_s=delay))
    for _ in range(races):
        results += [fp.race(bench, wait=False), fp.race(bench, wait=True)]
    return results


def summarise(results: list[fc.Result]) -> dict[str, dict[str, int]]:
    table: dict[str, Counter[str]] = {}
    for r in results:
        row = table.setdefault(r.cls, Counter())
        row["tried"] += 1
        row["caught"] += r.caught
        row["survived"] += r.survived
        row["lost"] += not r.survived
    return {cls: dict(row) for cls, row in sorted(table.items())}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=("real", "synth"), default="real")
    parser.add_argument("--variant", default="snow")
    parser.add_argument("--kills", type=int, default=24)
    parser.add_argument("--races", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv if argv is not None else sys.argv[1:])
    start = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix="lads-faults-"))
    try:
        make = real_source if args.source == "real" else synth_source
        bench = fc.Bench(make(work / "source"), work, variant=args.variant)
        results = run_campaign(bench, args.kills, args.races, args.seed)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    payload = {
        "command": "python -m benchmarks.faults " + " ".join(argv or sys.argv[1:]),
        "source": args.source,
        "variant": args.variant,
        "classes": summarise(results),
        "faults": [r.to_json() for r in results],
        "seconds": round(time.perf_counter() - start, 1),
        "machine": machine_info(),
    }
    path = write_result("faults.json", payload)
    for cls, row in payload["classes"].items():
        sys.stdout.write(
            f"{cls:11s} tried {row['tried']:3d}  caught {row['caught']:3d}  "
            f"survived {row['survived']:3d}  lost {row['lost']:3d}\n"
        )
    sys.stdout.write(f"faults -> {path}\n")
    return payload


if __name__ == "__main__":
    main()
