"""provenance.zarr: the store's attributes and each ok item's group against run.json and
the manifest (read from the zarr.json metadata files, without opening the arrays)."""

from __future__ import annotations

import json
from typing import Any
from urllib.parse import quote

from lads.verify.state import Verifier

ROOT_META = "provenance.zarr/zarr.json"


def provenance_group(scan_relpath: str) -> str:
    """The provenance.zarr subgroup name of an item: its scan relpath, percent-quoted."""
    return quote(scan_relpath, safe="")


def check_provenance(v: Verifier) -> None:
    root = _zarr_json(v, ROOT_META)
    if root is None:
        return
    attrs = root.get("attributes") or {}
    for key in ("points_mode", "config_hash"):
        if key in v.run_json and attrs.get(key) != v.run_json[key]:
            what = f"attribute {key} is {attrs.get(key)!r}, run.json {v.run_json[key]!r}"
            v.add("provenance.zarr", "provenance_mismatch", what)
    for row in v.ok_rows():
        scan_rel = row["item_id"].partition(":")[2]
        group = f"provenance.zarr/{provenance_group(scan_rel)}"
        pts = row["points"] if isinstance(row.get("points"), dict) else {}
        want = {"item_id": row["item_id"], "relpath": scan_rel}
        want |= {"n_source": pts.get("source"), "n_output": pts.get("output")}
        meta = _zarr_json(v, f"{group}/zarr.json")
        got = {k: (meta or {}).get("attributes", {}).get(k) for k in want}
        if meta is not None and got != want:
            v.add(group, "provenance_mismatch", f"attributes {got}, manifest {want}")
        for array in ("source_index", "outcome"):
            meta = _zarr_json(v, f"{group}/{array}/zarr.json")
            if meta is not None and meta.get("shape") != [pts.get("output")]:
                what = f"shape {meta.get('shape')}, expected [{pts.get('output')}]"
                v.add(f"{group}/{array}", "provenance_mismatch", what)


def _zarr_json(v: Verifier, rel: str) -> dict[str, Any] | None:
    if rel not in v.files:
        if rel != ROOT_META and ROOT_META in v.files:
            v.add(rel, "provenance_mismatch", "missing (one group per ok item)")
        return None
    try:
        meta = json.loads((v.out / rel).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        v.add(rel, "provenance_mismatch", f"unreadable zarr metadata ({exc})")
        return None
    return meta if isinstance(meta, dict) else {}
