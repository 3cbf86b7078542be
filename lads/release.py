"""`make release`: build, verify and document the LADS table.

The table (paper, "LiDAR Adaptation Dataset Suite"): SemanticKITTI sequences 00-10 and
nuScenes lidarseg keyframes, each x {snow, rain}; Voxelscape 00-10 x {snow, rain}. Dataset
roots come from environment variables:

    LADS_SEMANTICKITTI_ROOT   folder holding sequences/ (SemanticKITTI)
    LADS_NUSCENES_ROOT        nuScenes dataroot (with lidarseg); LADS_NUSCENES_VERSION
    LADS_VOXELSCAPE_ROOT      folder holding the Voxelscape sequence folders
    LADS_RELEASE_OUT          where the release goes (default: release/)
    LADS_JOBS                 worker processes (default: all cores)

Without any root it builds the same table from synthetic sources (`lads synth` in the
SemanticKITTI, nuScenes and Voxelscape layouts) into a demo release and says so: that exercises
every step a real release runs. Each built tree gets its dataset card (README.md), and its
SHA256SUMS, manifest.jsonl and run.json are collected under <out>/manifests/<entry>/.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lads.built_tree import MANIFEST, RUN_JSON, SHA256SUMS
from lads.config import pipeline_for
from lads.errors import LadsError
from lads.exit_codes import EXIT_LADS_ERROR
from lads.runner import run_build
from lads.verify import verify_tree

RELEASE_VARIANTS = ("snow", "rain")
KITTI_SEQUENCES = [f"{s:02d}" for s in range(11)]


@dataclass(frozen=True, slots=True)
class Entry:
    """One (source, variant) cell of the release table."""

    source: str
    root: Path
    variant: str
    options: tuple[tuple[str, Any], ...]
    inventory: str | None

    @property
    def name(self) -> str:
        return f"{self.source}-{self.variant}"


def table_from_env(env: dict[str, str]) -> list[Entry]:
    """The release table for the dataset roots named in `env` (empty if none)."""
    sources: list[tuple[str, Path, tuple[tuple[str, Any], ...], str | None]] = []
    if env.get("LADS_SEMANTICKITTI_ROOT"):
        sources.append(
            (
                "semantickitti",
                Path(env["LADS_SEMANTICKITTI_ROOT"]),
                (("sequences", tuple(KITTI_SEQUENCES)),),
                "semantickitti-00-10",
            )
        )
    if env.get("LADS_NUSCENES_ROOT"):
        version = env.get("LADS_NUSCENES_VERSION", "v1.0-trainval")
        sources.append(
            (
                "nuscenes",
                Path(env["LADS_NUSCENES_ROOT"]),
                (("version", version),),
                f"nuscenes-{version}",
            )
        )
    if env.get("LADS_VOXELSCAPE_ROOT"):
        sources.append(
            (
                "voxelscape",
                Path(env["LADS_VOXELSCAPE_ROOT"]),
                (("sequences", tuple(KITTI_SEQUENCES)),),
                None,
            )
        )
    return [
        Entry(s, root, v, opts, inv) for s, root, opts, inv in sources for v in RELEASE_VARIANTS
    ]


# Demo-release sources: (table source = reader, `lads synth` layout), in table order.
SYNTHETIC_SOURCES = ("semantickitti", "nuscenes", "voxelscape")


def synthetic_table(out: Path, frames: int, seed: int) -> list[Entry]:
    """The same table from synthetic sources lads writes itself (demo release): one
    `lads synth` tree per source under <out>/sources/synthetic-<source>, each in its own
    sensor (hdl64e; hdl32e for nuScenes), written once and reused when present."""
    from lads.synth import write_synthetic_dataset

    entries = []
    for source in SYNTHETIC_SOURCES:
        root = out / "sources" / f"synthetic-{source}"
        if not root.exists():
            write_synthetic_dataset(root, frames=frames, layout=source, seed=seed)
        entries += [Entry(source, root, variant, (), None) for variant in RELEASE_VARIANTS]
    return entries


def build_entry(entry: Entry, out: Path, *, seed: int, jobs: int) -> dict[str, Any]:
    """Build, verify and collect the manifests of one table entry."""
    pipeline = pipeline_for(entry.source, entry.variant)
    tree = out / entry.name
    report = run_build(
        entry.source,
        entry.root,
        tree,
        pipeline,
        seed=seed,
        reader_options=dict(entry.options),
        jobs=jobs,
        progress=None,
        figures=True,
    )
    check = verify_tree(tree, entry.root, regenerate=2, seed=seed, inventory=entry.inventory)
    manifests = out / "manifests" / entry.name
    manifests.mkdir(parents=True, exist_ok=True)
    for name in (SHA256SUMS, MANIFEST, RUN_JSON, "README.md"):
        if (tree / name).is_file():
            shutil.copyfile(tree / name, manifests / name)
    return {
        "entry": entry.name,
        "tree": str(tree),
        "items": report.items,
        "failed": len(report.failed),
        "frames_per_s": round(report.frames_per_s, 2),
        "verify_ok": check.ok,
        "problems": [f"{p.kind}: {p.path}: {p.message}" for p in check.problems][:50],
    }


def main(argv: list[str] | None = None) -> int:
    """`make release`; a LadsError (a root without the release's sequences, a bad build
    setting) is one line on stderr and exit code EXIT_LADS_ERROR, as the CLI's."""
    try:
        return _release(argv)
    except LadsError as exc:
        sys.stderr.write(f"make release: error: {exc}\n")
        return EXIT_LADS_ERROR


def _release(argv: list[str] | None) -> int:
    parser = argparse.ArgumentParser(description="Build, verify and document the LADS table.")
    parser.add_argument("--frames", type=int, default=6, help="frames per synthetic source")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    env = dict(os.environ)
    out = Path(env.get("LADS_RELEASE_OUT", "release")).resolve()
    jobs = int(env.get("LADS_JOBS", os.cpu_count() or 1))
    table = table_from_env(env)
    demo = not table
    if demo:
        sys.stdout.write(
            "make release: no LADS_*_ROOT set, so this is a DEMO release built from synthetic "
            "sources (same table, same steps). Set LADS_SEMANTICKITTI_ROOT, LADS_NUSCENES_ROOT "
            "or LADS_VOXELSCAPE_ROOT to build the real one.\n"
        )
        table = synthetic_table(out, args.frames, args.seed)
    results = [build_entry(e, out, seed=args.seed, jobs=jobs) for e in table]
    summary = {"demo_release": demo, "out": str(out), "entries": results}
    (out / "release.json").write_text(json.dumps(summary, indent=2) + "\n")
    for r in results:
        verdict = "verified" if r["verify_ok"] and not r["failed"] else "PROBLEMS"
        sys.stdout.write(f"{r['entry']:24s} {r['items']:7d} items  {verdict}\n")
    sys.stdout.write(
        f"release in {out} ({'demo, synthetic sources' if demo else 'real sources'})\n"
    )
    return 0 if all(r["verify_ok"] and not r["failed"] for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
