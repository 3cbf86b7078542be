"""Every shipped variant of every source, built with its default settings on real frames of
../shared/data through the `lads` command a user runs, then verified against its source.

`python -m benchmarks.variant_sweep` → benchmarks/results/variant_sweep.json. The command is
the `lads` beside this Python (in a venv made from the wheel it is the installed package, not
the checkout). Each (source, variant) builds the first `--frames` items (3 by default; `--all`:
every frame) with `--jobs 2` and verifies with one item regenerated; the corruption variants
run at the heavy severity unless `--all-severities`. Variants that read poses (`sensor-*`,
`motion-recorded`) run on the trees with poses. tests/realdata/test_matrix_real.py covers
the five weather and intensity variants on every frame; this sweep covers the rest.
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

from tqdm import tqdm

from benchmarks.common import SHARED_DATA, machine_info, write_result
from benchmarks.sensor_transfer_real import kitti_tree
from lads.errors import InputDataError
from tests.real_trees import (
    real_nuscenes_kitti,
    real_nuscenes_scans,
    real_nuscenes_scene0001,
    real_semantickitti_all,
    real_wads_all,
)

# Covered on every frame by the real-data matrix test.
MATRIX = ("snow", "rain", "fog", "intensity-kitti", "intensity-nuscenes")
SEVERITY_SLOT = "<light|moderate|heavy>"


def _needs_poses(variant: str) -> bool:
    return variant.startswith("sensor-") or variant == "motion-recorded"


def trees(tmp: Path) -> list[tuple[str, Path, str]]:
    """(source, root, which variants) of every real tree the sweep builds from: "all", the
    variants without poses ("no poses") or those with ("poses": SemanticKITTI's frames with
    the KITTI odometry poses, since its other real frames have none)."""
    if not SHARED_DATA.is_dir():
        raise InputDataError(f"real frames missing at {SHARED_DATA} (../shared/data).")
    return [
        ("semantickitti", real_semantickitti_all(tmp / "sk"), "no poses"),
        ("semantickitti", kitti_tree(tmp / "sk_poses"), "poses"),
        ("wads", real_wads_all(tmp / "wads"), "no poses"),
        ("nuscenes", real_nuscenes_scene0001(tmp / "ns"), "all"),
        ("nuscenes-kitti", real_nuscenes_kitti(tmp / "nk"), "all"),
        ("nuscenes-scans", real_nuscenes_scans(tmp / "nsc"), "no poses"),
        ("radiate", SHARED_DATA / "radiate", "no poses"),
    ]


def variants_of(lads: str, source: str, severities: tuple[str, ...]) -> list[str]:
    """The variants `lads variants` lists for `source`, the matrix's left out, each
    corruption at `severities`."""
    listing = subprocess.run([lads, "variants"], capture_output=True, text=True, check=True)
    names = [row.split()[1] for row in listing.stdout.splitlines() if row.split()[:1] == [source]]
    out = []
    for name in names:
        if name in MATRIX:
            continue
        out += (
            [name.replace(SEVERITY_SLOT, s) for s in severities]
            if SEVERITY_SLOT in name
            else [name]
        )
    return out


def _tail(text: str) -> str:
    return " / ".join(line for line in text.strip().splitlines()[-3:])[-400:]


def run_one(
    lads: str, source: str, root: Path, variant: str, out: Path, frames: int | None
) -> dict[str, Any]:
    limit = [] if frames is None else ["--limit", str(frames)]
    start = time.perf_counter()
    build = subprocess.run(
        [lads, "build", "--source", source, "--in", str(root), "--out", str(out),
         "--variant", variant, "--jobs", "2", "--no-figures", *limit],
        capture_output=True, text=True,
    )  # fmt: skip
    seconds = time.perf_counter() - start
    row: dict[str, Any] = {"source": source, "variant": variant, "build_rc": build.returncode}
    report = out / "run_report.json"
    if report.is_file():
        data = json.loads(report.read_text())
        row |= {"built": data["built"], "failed": len(data["failed"])}
    row["seconds"] = round(seconds, 1)
    if build.returncode != 0:
        row["build_said"] = _tail(build.stderr + build.stdout)
    if build.returncode in (0, 1):
        check = subprocess.run(
            [lads, "verify", str(out), "--against", str(root), "--regenerate", "1"],
            capture_output=True, text=True,
        )  # fmt: skip
        row["verify_rc"] = check.returncode
        if check.returncode != 0:
            row["verify_said"] = _tail(check.stdout + check.stderr)
    row["ok"] = build.returncode == 0 and row.get("verify_rc") == 0
    return row


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3, help="items per build (default 3)")
    parser.add_argument("--all", action="store_true", help="every frame of every tree")
    parser.add_argument("--all-severities", action="store_true")
    args = parser.parse_args(argv)
    lads = str(Path(sys.executable).with_name("lads"))
    severities = ("light", "moderate", "heavy") if args.all_severities else ("heavy",)
    frames = None if args.all else args.frames
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        jobs = [
            (k, source, root, variant)
            for k, (source, root, which) in enumerate(trees(tmp))
            for variant in variants_of(lads, source, severities)
            if which == "all" or _needs_poses(variant) == (which == "poses")
        ]
        for k, source, root, variant in tqdm(jobs, desc="variants", unit="build"):
            out = tmp / f"out_{k}_{variant}"
            rows.append(run_one(lads, source, root, variant, out, frames))
            shutil.rmtree(out, ignore_errors=True)
    result = {
        "what": "every shipped variant (the real-data matrix's five left out) on real frames, "
        "built with its defaults by the lads command and verified with one item regenerated",
        "command": "python -m benchmarks.variant_sweep" + (" " + " ".join(argv) if argv else ""),
        "lads": lads,
        "frames_per_build": frames or "all",
        "severities": list(severities),
        "machine": machine_info(),
        "builds": len(rows),
        "ok": sum(r["ok"] for r in rows),
        "not_ok": [r for r in rows if not r["ok"]],
        "rows": rows,
    }
    write_result("variant_sweep.json", result)
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
