"""The end of a build: manifest, effective pipeline, run.json, card, SHA256SUMS.

Everything here is deterministic (sorted rows, no timestamps), so a resumed build and an
uninterrupted one finish with the same bytes.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import yaml

import lads
from lads import provenance
from lads.built_tree import (
    MANIFEST,
    NOT_SUMMED,
    PIPELINE_YAML,
    PREVIEW,
    RUN_JSON,
    SHA256SUMS,
    STATE_DIR,
    BuildPlan,
    identity,
)
from lads.files import atomic_write, sha256_file
from lads.frame import Item
from lads.run_info import git_commit, library_versions
from lads.worker import reader_for, writer_for


def finalise(
    out_root: Path,
    plan: BuildPlan,
    items: list[Item],
    rows: dict[str, dict[str, Any]],
    copied: list[dict[str, Any]],
    *,
    figures: bool,
    limit: int | None = None,
    source_items: int | None = None,
) -> list[str]:
    """Write the tree's metadata, card and SHA256SUMS; returns the relpaths of files in the
    tree that this build did not write (left out of SHA256SUMS, for the report).

    `items` are the items the tree holds; `limit` the build's --limit and `source_items`
    how many items the source has (run.json records both: verify and the card tell a trial
    subset from a complete variant)."""
    manifest = [rows[i.item_id] for i in sorted(items, key=lambda i: i.item_id)]
    lines = "".join(json.dumps(r, sort_keys=True) + "\n" for r in manifest)
    atomic_write(out_root / MANIFEST, lines.encode())
    atomic_write(
        out_root / PIPELINE_YAML, yaml.safe_dump(plan.pipeline.to_dict(), sort_keys=True).encode()
    )
    run = {
        **identity(plan),
        "lads_version": lads.__version__,
        "git_commit": git_commit(),
        "variant": plan.pipeline.variant,
        "source_root": plan.source_root,
        "points_mode": plan.pipeline.points,
        "point_format": plan.pipeline.point_format,
        # What the scan files hold: readers of this tree read these (`lads.readers.get_reader`).
        "point_columns": list(writer_for(plan).columns),
        "source_point_columns": list(reader_for(plan).columns),
        "sensor": plan.pipeline.output_sensor(reader_for(plan).sensor),
        "device": _device(plan),
        "libraries": library_versions(),
        "items": len(manifest),
        "failed": sum(r["status"] != "ok" for r in manifest),
        "limit": limit,
        "source_items": len(manifest) if source_items is None else source_items,
        "copied_files": copied,
    }
    atomic_write(out_root / RUN_JSON, (json.dumps(run, sort_keys=True, indent=1) + "\n").encode())
    from lads.card import write_card

    drawn = _preview(out_root, plan, manifest) if figures else []
    write_card(out_root, figures=drawn)
    shutil.rmtree(out_root / STATE_DIR, ignore_errors=True)
    known = {o["path"]: o["sha256"] for r in manifest for o in r["outputs"]}
    known |= {c["path"]: c["sha256"] for c in copied}
    sums, foreign = _sha256sums(out_root, known, _owned(manifest))
    atomic_write(out_root / SHA256SUMS, sums.encode())
    return foreign


def _device(plan: BuildPlan) -> str:
    """Where the build computed: the learned stage's device, else the CPU."""
    stages = plan.pipeline.stages
    devices = {s.params.get("device", "cpu") for s in stages if s.stage == "intensity"}
    return ",".join(sorted(devices)) or "cpu"


def _preview(out_root: Path, plan: BuildPlan, manifest: list[dict[str, Any]]) -> list[str]:
    """Draw the card's preview figure from the first built item; [] for text formats."""
    from lads.figures import variant_figure

    first = next((r for r in manifest if r["status"] == "ok"), None)
    scan = next((o for o in first["outputs"] if o["role"] == "scan"), None) if first else None
    if scan is None or scan["record_bytes"] == 0:
        return []
    reader = reader_for(plan)
    relpath = PREVIEW
    variant_figure(
        Path(reader.root),
        {plan.pipeline.variant: out_root},
        scan["path"],
        out_root / relpath,
        sensor=reader.sensor,
        columns=len(reader.columns),
        variant_columns=scan["record_bytes"] // 4,
        variant_sensor=plan.pipeline.output_sensor(reader.sensor),
    )
    return [relpath]


def refresh_card(out_root: Path) -> Path:
    """Re-render the dataset card (OUT/README.md) of a finished build from its run.json,
    manifest.jsonl and pipeline.yaml, and update the card's line in SHA256SUMS; every other
    file and line is left as it is. Returns the card's path.

    Raises:
        BuildError: the tree has no SHA256SUMS (not a finished build).
        ManifestError: run.json or manifest.jsonl is missing or not JSON.
    """
    from lads import lock
    from lads.card import CARD_NAME, write_card
    from lads.errors import BuildError

    owner = lock.holder(out_root)
    if owner is not None:
        raise BuildError(
            f"{out_root}: {lock.describe(owner)} is writing this tree now; the build writes the "
            "card when it finishes (run `lads card` after it to re-render one)."
        )
    sums = out_root / SHA256SUMS
    if not sums.is_file():
        raise BuildError(
            f"{sums}: missing; a card is refreshed on a finished build. Run (or resume) "
            "`lads build` with the same settings first."
        )
    figures = [PREVIEW] if (out_root / PREVIEW).is_file() else []
    card = write_card(out_root, figures=figures)
    entries = [line for line in sums.read_text().splitlines() if line[66:] != CARD_NAME]
    entries.append(f"{sha256_file(card)}  {CARD_NAME}")
    entries.sort(key=lambda line: line[66:].encode())
    atomic_write(sums, "".join(f"{line}\n" for line in entries).encode())
    return card


def _owned(manifest: list[dict[str, Any]]) -> tuple[set[str], tuple[str, ...]]:
    """What the build writes besides item outputs and copies: (exact relpaths, prefixes of
    the provenance groups of its ok items)."""
    from lads.card import CARD_NAME

    exact = {
        MANIFEST,
        PIPELINE_YAML,
        RUN_JSON,
        CARD_NAME,
        PREVIEW,
        f"{provenance.STORE_NAME}/zarr.json",
    }
    groups = tuple(
        f"{provenance.STORE_NAME}/{provenance.node_name(r['item_id'].partition(':')[2])}/"
        for r in manifest
        if r["status"] == "ok"
    )
    return exact, groups


def _sha256sums(
    out_root: Path, known: dict[str, str], owned: tuple[set[str], tuple[str, ...]]
) -> tuple[str, list[str]]:
    """SHA256SUMS over the files this build wrote, and the sorted list of the others."""
    exact, groups = owned
    entries, foreign = [], []
    for folder, dirs, files in os.walk(out_root):
        dirs[:] = [d for d in dirs if d != STATE_DIR]
        for name in files:
            rel = Path(folder, name).relative_to(out_root).as_posix()
            if rel in NOT_SUMMED:
                continue
            if rel in known:
                entries.append((rel, known[rel]))
            elif rel in exact or rel.startswith(groups):
                entries.append((rel, sha256_file(out_root / rel)))
            else:
                foreign.append(rel)
    entries.sort(key=lambda e: e[0].encode())
    return "".join(f"{digest}  {rel}\n" for rel, digest in entries), sorted(foreign)
