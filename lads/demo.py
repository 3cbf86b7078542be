"""`make demo`: the whole product on data lads makes itself, no dataset needed.

1. `lads synth`: ray-cast a short SemanticKITTI-layout sequence through a procedural street.
2. `lads build`: snow, rain and fog variants of it (same layout, labels rewritten).
3. `lads verify`: every variant against the source (checksums, layout, counts, a regenerated
   item).
4. Figures: bird's-eye view and range image before/after, intensity histograms, and the
   point-correspondence diagram; `summary.json` and a one-screen summary.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from lads.config import pipeline_for
from lads.figures import correspondence_figure, variant_figure
from lads.files import make_folder
from lads.runner import run_build
from lads.synth import write_synthetic_dataset
from lads.verify import verify_tree

VARIANTS = ("snow", "rain", "fog")
MARKER = "lads_demo.json"


def _fresh(out_dir: Path) -> None:
    """Start from an empty demo folder; only ever delete a folder the demo made."""
    if out_dir.exists() and not out_dir.is_dir():
        from lads.errors import BuildError

        raise BuildError(f"{out_dir}: is a file, not a folder; pass another --out.")
    if out_dir.exists() and any(out_dir.iterdir()):
        if not (out_dir / MARKER).is_file():
            from lads.errors import BuildError

            raise BuildError(
                f"{out_dir}: not empty and not a lads demo folder; pass another --out."
            )
        shutil.rmtree(out_dir)
    make_folder(out_dir)
    (out_dir / MARKER).write_text('{"made_by": "lads demo"}\n')


def run_demo(
    out_dir: Path, *, frames: int = 8, sensor: str = "hdl64e", seed: int = 0, jobs: int = 2
) -> dict[str, Any]:
    """Synthesise, build every variant, verify, draw. Returns the summary (also as JSON)."""
    _fresh(out_dir)
    start = time.perf_counter()
    source = out_dir / "source"
    synth = write_synthetic_dataset(source, sensor=sensor, frames=frames, seed=seed)
    summary: dict[str, Any] = {
        "sensor": sensor,
        "frames": frames,
        "seed": seed,
        "source": str(source),
        "source_points_per_frame": list(synth.points_per_frame),
        "synth_seconds": round(time.perf_counter() - start, 2),
        "variants": {},
    }
    built: dict[str, Path] = {}
    for variant in VARIANTS:
        pipeline = pipeline_for("semantickitti", variant)
        out = out_dir / variant
        report = run_build("semantickitti", source, out, pipeline, seed=seed, jobs=jobs)
        check = verify_tree(out, source, regenerate=1, seed=seed)
        rows = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
        totals = {k: sum(r["points"][k] for r in rows) for k in rows[0]["points"]}
        built[variant] = out
        summary["variants"][variant] = {
            "tree": str(out),
            "stage": pipeline.stages[0].to_dict(),
            "complete": report.complete,
            "frames_per_s": round(report.frames_per_s, 2),
            "points": totals,
            "verify_ok": check.ok,
            "verify_problems": [f"{p.kind}: {p.path}" for p in check.problems],
        }
    figures = out_dir / "figures"
    relpath = "sequences/00/velodyne/000000.bin"
    variant_figure(source, built, relpath, figures / "variants_000000.png", sensor=sensor)
    correspondence_figure(figures / "point_correspondence.png")
    summary["figures"] = sorted(p.name for p in figures.glob("*.png"))
    summary["seconds"] = round(time.perf_counter() - start, 2)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def summary_text(summary: dict[str, Any], out_dir: Path) -> str:
    n = summary["frames"]
    mean_pts = sum(summary["source_points_per_frame"]) / max(n, 1)
    lines = [
        f"lads demo: {n} synthetic {summary['sensor']} frames ({mean_pts:,.0f} points each) "
        f"in {out_dir / 'source'}",
        f"{'variant':8s} {'stage':34s} {'particle':>9s} {'lost':>8s} {'frames/s':>9s}  verify",
    ]
    for name, info in summary["variants"].items():
        stage = ", ".join(f"{k}={v}" for k, v in info["stage"].items() if k != "stage")
        p = info["points"]
        verdict = "ok" if info["verify_ok"] else f"{len(info['verify_problems'])} problems"
        lines.append(
            f"{name:8s} {stage:34s} {p['particle']:9,d} {p['lost']:8,d} "
            f"{info['frames_per_s']:9.1f}  {verdict}"
        )
    lines.append(f"figures: {out_dir / 'figures'} ({', '.join(summary['figures'])})")
    lines.append(f"total {summary['seconds']:.1f} s; details in {out_dir / 'summary.json'}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("demo_output"))
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--sensor", default="hdl64e")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    summary = run_demo(
        args.out, frames=args.frames, sensor=args.sensor, seed=args.seed, jobs=args.jobs
    )
    sys.stdout.write(summary_text(summary, args.out) + "\n")
    ok = all(v["verify_ok"] and v["complete"] for v in summary["variants"].values())
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
