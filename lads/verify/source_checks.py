"""Checks against the source tree and beyond the tree itself: copied files, the sources the
manifest names, the one-to-one correspondence of items, K regenerated items and the expected
inventory of a release.

`lads.readers`, `lads.worker` and `lads.inventory` are imported when a check runs, not at
import time: verify works without the first two (the check then notes or reports why), and
tests replace `lads.readers` in sys.modules or patch `lads.worker.regenerate_outputs`.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import numpy as np

from lads.errors import LadsError
from lads.verify.state import Verifier, entries


def check_copied(v: Verifier) -> None:
    outputs = {o["path"] for r in v.rows for o in entries(r, "outputs")}
    for entry in v.copied():
        rel = entry["path"]
        if rel in outputs:
            v.add(rel, "manifest_inconsistent", "both a copied file and an item output")
        if rel not in v.files:
            if rel not in v.sums:
                v.add(rel, "missing_output", "copied file (run.json) is absent")
            continue
        if v.files[rel] != entry.get("bytes"):
            what = f"{v.files[rel]} bytes, run.json says {entry.get('bytes')}"
            v.add(rel, "size_mismatch", what)
        if v.sums.get(rel) != entry.get("sha256"):
            what = f"run.json sha256 {entry.get('sha256')}, SHA256SUMS {v.sums.get(rel)}"
            v.add(rel, "manifest_inconsistent", what)
        if v.src is not None:
            src = v.src_digests.get(rel)
            if src is None or src != v.digests.get(rel):
                why = "absent or unreadable in" if src is None else "different from"
                v.add(rel, "copied_file_differs", f"{why} the source {v.src / rel}")


def check_sources(v: Verifier) -> None:
    for row in v.ok_rows():
        for s in entries(row, "source"):
            got = v.src_digests.get(s["path"])
            if got != s.get("sha256"):
                why = "is absent or unreadable" if got is None else f"has sha256 {got}"
                what = f"source of {row['item_id']} {why}; the build saw {s.get('sha256')}"
                v.add(s["path"], "source_changed", what)


def resolve_source_root(v: Verifier) -> None:
    """The source root as the tree's reader takes it: a reader may step into a folder of the
    given one (SemanticKITTI's and Voxelscape's `dataset/`), and the manifest's source paths
    are relative to where it stepped. Left as given when the reader cannot be made."""
    name = v.run_json.get("source")
    options = v.run_json.get("reader_options") or {}
    if not isinstance(name, str) or v.src is None:
        return
    try:
        get_reader = importlib.import_module("lads.readers").get_reader
        root = Path(get_reader(name, v.src, **(options if isinstance(options, dict) else {})).root)
    except (ImportError, AttributeError, TypeError, LadsError):
        return
    if root.is_dir():
        v.src = root


def check_source_items(v: Verifier, source_items: list[str] | None) -> None:
    if source_items is None:
        source_items = _list_source_items(v)
        if source_items is None:
            return
    have = {r["item_id"] for r in v.rows if isinstance(r.get("item_id"), str)}
    want = set(source_items)
    trial = _trial_items(v, source_items)
    missing = sorted(want - have)
    for item in missing:
        if item in trial:
            continue
        what = f"source item {item} has no row in manifest.jsonl"
        v.add(item.partition(":")[2], "missing_source_item", what)
    if trial & set(missing):
        v.notes.append(
            f"a trial subset (built with --limit {v.run_json['limit']}): "
            f"{len(trial & set(missing))} of the source's {len(want)} items are not in the "
            "tree; build without --limit to complete it"
        )
    for item in sorted(have - want):
        v.add(item.partition(":")[2], "extra_output_item", f"{item} is not in the source")


def _trial_items(v: Verifier, source_items: list[str]) -> set[str]:
    """The source items a --limit build left out on purpose: those after its first `limit`
    (in the reader's order, as the build takes them); none for a build without a limit."""
    limit = v.run_json.get("limit")
    if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
        return set()
    return set(source_items[limit:])


def _list_source_items(v: Verifier) -> list[str] | None:
    name = v.run_json.get("source")
    try:
        get_reader = importlib.import_module("lads.readers").get_reader
    except (ImportError, AttributeError) as exc:
        v.notes.append(
            f"source item correspondence not checked: lads.readers.get_reader is not "
            f"available ({exc}); pass source_items to check it"
        )
        return None
    if not isinstance(name, str):
        v.notes.append("source item correspondence not checked: run.json names no reader")
        return None
    options = v.run_json.get("reader_options") or {}
    try:
        reader = get_reader(name, v.src, **(options if isinstance(options, dict) else {}))
        _check_copied_list(v, reader)
        return [it.item_id for it in reader.items()]
    except LadsError as exc:
        v.add(".", "source_unreadable", f"reader {name!r} cannot list the source: {exc}")
        return None


def _check_copied_list(v: Verifier, reader: Any) -> None:
    listed = {c["path"] for c in v.copied()}
    for rel in sorted(set(reader.copied_files()) - listed):
        v.add(rel, "missing_output", "a file to copy from the source is not in the tree")


def check_regenerated(v: Verifier, k: int, seed: int) -> None:
    rows = sorted(v.ok_rows(), key=lambda r: r["item_id"])
    if v.src is None:
        v.add(".", "regenerate_no_source", f"--regenerate {k} rebuilds items from their source")
        return
    if not rows:
        v.add(".", "regenerate_nothing_built", f"--regenerate {k}: the tree has no built item")
        return
    picks = np.random.default_rng(seed).choice(len(rows), size=min(k, len(rows)), replace=False)
    chosen = [rows[i] for i in sorted(int(i) for i in picks)]
    ids = [r["item_id"] for r in chosen]
    try:
        from lads.worker import regenerate_outputs

        got = regenerate_outputs(v.out, v.src, ids)
    except (ImportError, AttributeError, LadsError) as exc:
        v.add(".", "regenerate_failed", f"cannot regenerate {ids}: {exc}")
        return
    v.regenerated = len(ids)
    for row in chosen:
        want = {o["path"]: o.get("sha256") for o in entries(row, "outputs")}
        have = got.get(row["item_id"], {})
        for path in sorted(set(want) | set(have)):
            if want.get(path) != have.get(path):
                what = f"{row['item_id']}: regenerated {have.get(path)}, manifest {want.get(path)}"
                v.add(path, "regenerated_differs", what)


def check_inventory(v: Verifier, release: str) -> None:
    from lads import inventory as inv

    name, subset = inv.parse_release(release)
    source = v.run_json.get("source")
    if isinstance(source, str) and source != name:
        v.add(".", "inventory_other_dataset", f"inventory {release!r} lists {name} items; this "
              f"tree was built from source {source!r}")  # fmt: skip
        return
    rows = v.ok_rows()
    version = inv.tree_version(v.run_json, [o["path"] for r in rows for o in entries(r, "outputs")])
    for path, kind, message in inv.compare(
        [r["item_id"] for r in rows], name, subset, version=version
    ):
        v.add(path, kind, message)
    v.notes.extend(inv.notes(name, subset))
