"""What a card reads from a built tree: run.json, manifest.jsonl, pipeline.yaml, and the
splits of the ok items (from the source inventory's groups)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from lads.card.sources import Source
from lads.errors import ManifestError


def read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ManifestError(f"{path}: cannot read ({exc}); a card needs a built tree.") from exc
    if not isinstance(data, dict):
        raise ManifestError(f"{path}: expected a JSON object; rebuild the tree.")
    return data


def read_manifest(path: Path) -> list[dict[str, Any]]:
    try:
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    except (OSError, json.JSONDecodeError) as exc:
        raise ManifestError(f"{path}: cannot read ({exc}); a card needs a built tree.") from exc


def read_text(path: Path) -> str:
    return path.read_text() if path.is_file() else "# pipeline.yaml missing from the tree\n"


def splits(run: dict[str, Any], ok: list[dict[str, Any]], src: Source) -> list[dict[str, Any]]:
    """Splits from the source inventory's groups (SemanticKITTI train/validation/test,
    nuScenes version), else one split "full"; bytes and counts from the manifest."""
    totals: dict[str, list[int]] = {}
    names = _split_names(run, ok) if src.hf_id else {}
    for row in ok:
        entry = totals.setdefault(names.get(str(row.get("item_id")), "full"), [0, 0])
        entry[0] += sum(int(o.get("bytes", 0)) for o in row.get("outputs", []))
        entry[1] += 1
    return [{"name": k, "num_bytes": v[0], "num_examples": v[1]} for k, v in sorted(totals.items())]


def _split_names(run: dict[str, Any], ok: list[dict[str, Any]]) -> dict[str, str]:
    from lads import inventory

    name = str(run.get("source", ""))
    if name not in inventory.available():
        return {}
    inv = inventory.load_inventory(name)
    version = inventory.tree_version(
        run, [o.get("path", "") for r in ok for o in r.get("outputs", [])]
    )
    out = {}
    for row in ok:
        item_id = str(row.get("item_id"))
        group = inventory.group_of(item_id, inv.group_by, version=version)
        spec = inv.groups.get(group or "")
        if group is None and inv.group_by == "nuscenes_version":
            out[item_id] = "sweeps"
        elif spec is not None and spec.split:
            out[item_id] = re.sub(r"\W", "_", spec.split)
    return out
