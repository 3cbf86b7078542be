"""The build metadata: reading SHA256SUMS, run.json and manifest.jsonl, then checking
manifest.jsonl against itself, run.json, SHA256SUMS and the file sizes (layout, record
counts, point arithmetic of the points mode)."""

from __future__ import annotations

import json
from typing import Any

from lads.correspondence import POINT_MODES
from lads.verify.hashing import SUMS, parse_sums
from lads.verify.state import Verifier, count, entries

METADATA = ("manifest.jsonl", "run.json", "pipeline.yaml", "provenance.zarr/zarr.json")
RUN_KEYS = (
    "lads_version", "git_commit", "config_hash", "source", "source_root", "variant", "seed",
    "points_mode", "sensor", "device", "libraries", "items", "failed", "copied_files",
)  # fmt: skip
POINT_KEYS = ("source", "output", "kept", "attenuated", "particle", "lost")
OUTPUT_KEYS = ("role", "bytes", "sha256", "records", "record_bytes")


def load_metadata(v: Verifier) -> None:
    """Read SHA256SUMS, run.json and manifest.jsonl into `v`; report missing metadata."""
    for rel in (SUMS, *METADATA):
        if rel not in v.files:
            v.add(rel, "missing_output", f"{rel} is missing (docs/output_tree.md)")
    if SUMS in v.files:
        v.sums, bad = parse_sums((v.out / SUMS).read_text(errors="replace"))
        for n, why in bad:
            v.add(SUMS, "sums_invalid", f"line {n}: {why}")
    if "run.json" in v.files:
        run = _json(v, "run.json", (v.out / "run.json").read_text(errors="replace"))
        v.run_json = run if isinstance(run, dict) else {}
    if "manifest.jsonl" in v.files:
        text = (v.out / "manifest.jsonl").read_text(errors="replace")
        for n, line in enumerate(text.splitlines(), 1):
            row = _json(v, f"manifest.jsonl line {n}", line)
            if isinstance(row, dict):
                v.rows.append(row)
            elif row is not None:
                v.add("manifest.jsonl", "manifest_inconsistent", f"line {n}: no object")


def _json(v: Verifier, where: str, text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        v.add(where.split(" ")[0], "manifest_inconsistent", f"{where}: bad JSON ({exc})")
        return None


def check_run_json(v: Verifier) -> None:
    run = v.run_json
    if not run:
        return
    missing = [k for k in RUN_KEYS if k not in run]
    if missing:
        v.add("run.json", "manifest_inconsistent", f"keys {missing} are missing")
    failed = sum(r.get("status") == "failed" for r in v.rows)
    for key, have in (("items", len(v.rows)), ("failed", failed)):
        if key in run and run[key] != have:
            what = f"{key} is {run[key]!r} but manifest.jsonl has {have}"
            v.add("run.json", "manifest_inconsistent", what)
    if run.get("points_mode") not in POINT_MODES:
        what = f"points_mode {run.get('points_mode')!r} is not one of {POINT_MODES}"
        v.add("run.json", "manifest_inconsistent", what)


def check_rows(v: Verifier) -> None:
    previous, unsorted_keys = "", 0
    owners: dict[str, str] = {}
    for n, row in enumerate(v.rows, 1):
        item_id = row.get("item_id")
        if not isinstance(item_id, str) or ":" not in item_id:
            what = f"line {n}: item_id {item_id!r} is not '<dataset>:<relpath>'"
            v.add("manifest.jsonl", "manifest_inconsistent", what)
            continue
        if item_id <= previous:
            how = "is listed twice" if item_id == previous else f"comes after {previous}"
            what = f"line {n}: {item_id} {how}; rows must be unique and sorted by item_id"
            v.add("manifest.jsonl", "manifest_inconsistent", what)
        previous = max(previous, item_id)
        unsorted_keys += list(row) != sorted(row)
        for out in entries(row, "outputs"):
            if out["path"] in owners:
                what = f"written by both {owners[out['path']]} and {item_id}"
                v.add(out["path"], "manifest_inconsistent", what)
            owners[out["path"]] = item_id
        _check_row(v, item_id, row)
    if unsorted_keys:
        what = f"{unsorted_keys} line(s) do not have sorted keys (canonical JSON)"
        v.add("manifest.jsonl", "manifest_inconsistent", what)


def _check_row(v: Verifier, item_id: str, row: dict[str, Any]) -> None:
    scan_rel = item_id.partition(":")[2]
    status, outputs = row.get("status"), entries(row, "outputs")
    if status == "failed":
        v.add(scan_rel, "failed_item", f"{item_id} failed: {row.get('error', '?')}")
        if outputs:
            v.add(scan_rel, "manifest_inconsistent", f"failed {item_id} lists outputs")
        return
    sources = {s["path"]: s for s in entries(row, "source")}
    if status != "ok" or not outputs or not sources:
        what = f"{item_id}: status {status!r}, {len(outputs)} outputs, {len(sources)} sources"
        v.add(scan_rel, "manifest_inconsistent", what + " (need 'ok' and both)")
        return
    for out in outputs:
        _check_output(v, item_id, out, sources)
    scans = [o for o in outputs if o.get("role") == "scan"]
    if len(scans) != 1 or scans[0]["path"] != scan_rel or scan_rel not in sources:
        what = f"{item_id}: the scan output must be the source scan's own relative path"
        v.add(scan_rel, "layout_mismatch", f"{what}, got {[o['path'] for o in scans]}")
    counted = [o for o in outputs if count(o.get("records"))]
    if scans and count(scans[0].get("records")):
        for out in counted:
            if out["records"] != scans[0]["records"]:
                what = (
                    f"{item_id}: {out.get('role')} holds {out['records']} records but "
                    f"the scan {scans[0]['path']} holds {scans[0]['records']} points"
                )
                v.add(out["path"], "label_count_mismatch", what)
    _check_points(v, item_id, row, scans[0] if len(scans) == 1 else None, sources)


def _check_output(v: Verifier, item_id: str, out: dict[str, Any], sources: dict[str, Any]) -> None:
    rel = out["path"]
    numbers = ("bytes", "records", "record_bytes")
    if any(k not in out for k in OUTPUT_KEYS) or not all(count(out[k]) for k in numbers):
        what = f"{item_id}: an output needs {OUTPUT_KEYS} (counts >= 0), got {out}"
        v.add(rel, "manifest_inconsistent", what)
        return
    if rel not in sources:
        what = f"{item_id}: not at the relative path of a source file ({sorted(sources)})"
        v.add(rel, "layout_mismatch", what)
    size = v.files.get(rel)
    if size is not None and size != out["bytes"]:
        v.add(rel, "size_mismatch", f"{size} bytes, the manifest says {out['bytes']}")
    elif size is None and rel not in v.sums:
        v.add(rel, "missing_output", f"output of {item_id} is absent")
    if v.sums.get(rel) != out["sha256"]:
        what = f"manifest sha256 {out['sha256']}, SHA256SUMS {v.sums.get(rel)}"
        v.add(rel, "manifest_inconsistent", what)
    rb = out["record_bytes"]
    if rb > 0 and out["records"] * rb != out["bytes"]:
        what = f"{out['records']} records x {rb} bytes != {out['bytes']} bytes (manifest)"
        v.add(rel, "record_count_mismatch", what)
    elif rb > 0 and size is not None and size % rb:
        what = f"{size} bytes is not a whole number of {rb}-byte records"
        v.add(rel, "record_count_mismatch", what)


def _check_points(
    v: Verifier, item_id: str, row: dict[str, Any], scan: dict[str, Any] | None, sources: Any
) -> None:
    where, pts = item_id.partition(":")[2], row.get("points")
    if not isinstance(pts, dict) or not all(count(pts.get(k)) for k in POINT_KEYS):
        v.add(where, "manifest_inconsistent", f"{item_id}: points {pts!r} lacks counts")
        return
    s, o, lost = pts["source"], pts["output"], pts["lost"]
    # Displaced points (a motion-distorted sweep) are returns too; older trees lack the key.
    returned = pts["kept"] + pts["attenuated"] + pts["particle"] + pts.get("displaced", 0)
    mode = v.run_json.get("points_mode")
    rules = [("output == scan records", scan is None or o == scan.get("records"))]
    if mode == "physical":
        rules += [("kept+attenuated+particle+displaced == output", returned == o)]
        second = pts.get("second_returns", 0)
        rules += [("output + lost == source + second_returns", o + lost == s + second)]
    elif mode == "resampled":
        resampled = pts.get("resampled", 0)
        rules += [("kept+attenuated+particle+resampled == output", returned + resampled == o)]
        rules += [("lost == 0 (a transfer loses no source beam)", lost == 0)]
    elif mode == "aligned":
        rules += [("output == source", o == s)]
        rules += [("kept+attenuated+particle+displaced+lost == source", returned + lost == s)]
    rules += _record_rules(v.run_json, scan, sources, s)
    for rule, holds in rules:
        if not holds:
            what = f"{item_id} ({mode} mode): {rule} fails for points {pts}"
            v.add(where, "manifest_inconsistent", what)
    for out in entries(row, "outputs") if mode == "aligned" else ():
        src = sources.get(out["path"])
        if out.get("role") != "scan" and src and src.get("sha256") != out.get("sha256"):
            v.add(out["path"], "aligned_label_differs", f"{item_id}: differs from source")


def _record_rules(
    run: dict[str, Any], scan: dict[str, Any] | None, sources: Any, n_source: int
) -> list[tuple[str, bool]]:
    """(rule, holds) for the point records of one item's scans (binary formats only): the
    output's record is 4 bytes per column run.json records (`point_columns`), the source
    scan holds its points in 4 bytes per `source_point_columns` (older trees lack both
    keys: the source's record is the output's)."""
    rb = scan.get("record_bytes", 0) if scan else 0
    if not (scan and rb):
        return []  # a text format (RADIATE) has no record size
    rules = []
    columns, source_columns = run.get("point_columns"), run.get("source_point_columns")
    if isinstance(columns, list) and columns:
        rules += [("scan record_bytes == 4 x run.json point_columns", rb == 4 * len(columns))]
    if isinstance(source_columns, list) and source_columns:
        rb = 4 * len(source_columns)
    src_bytes = sources.get(scan["path"], {}).get("bytes")
    if count(src_bytes):
        rules += [("source bytes == source x source record_bytes", src_bytes == n_source * rb)]
    return rules
