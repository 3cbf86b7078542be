"""`lads verify`: check a built variant tree against docs/output_tree.md and its source.

Every problem is reported, never only the first: (1) SHA256SUMS against the files on disk;
(2) manifest.jsonl against itself, SHA256SUMS, run.json and the file sizes; (3) the
provenance store's per-item metadata; (4) with a source root, the one-to-one correspondence
of items and files with the source; (5) optionally K regenerated items; (6) the expected
inventory of a release; (7) the dataset card's front matter. `ADVICE` lists every problem
kind with what to do about it.
"""

from __future__ import annotations

import fnmatch
import hashlib
import importlib
import json
import logging
import os
import re
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np

from lads.errors import LadsError

log = logging.getLogger(__name__)

SUMS = "SHA256SUMS"
NOT_SUMMED = frozenset({SUMS, "run_report.json"})
BUILD_STATE_DIR = ".lads-state"  # lads.worker.STATE_DIR, removed when a build finishes
METADATA = ("manifest.jsonl", "run.json", "pipeline.yaml", "provenance.zarr/zarr.json")
RUN_KEYS = (
    "lads_version", "git_commit", "config_hash", "source", "source_root", "variant", "seed",
    "points_mode", "sensor", "device", "libraries", "items", "failed", "copied_files",
)  # fmt: skip
POINT_KEYS = ("source", "output", "kept", "attenuated", "particle", "lost")
OUTPUT_KEYS = ("role", "bytes", "sha256", "records", "record_bytes")
REBUILD = "rebuild the item (lads build resumes) or restore the file from the release"
ADVICE = {
    "missing_output": REBUILD,
    "extra_file": "remove it, or rebuild so that SHA256SUMS covers it",
    "stray_temp_file": "an interrupted write left it: delete it and re-run the build",
    "sums_invalid": "regenerate SHA256SUMS (GNU format, two spaces, sorted by path)",
    "unreadable_file": "fix its permissions or restore it",
    "checksum_mismatch": f"the file changed or is corrupt: {REBUILD}",
    "size_mismatch": f"the file is truncated or altered: {REBUILD}",
    "record_count_mismatch": f"file and manifest disagree: {REBUILD}",
    "label_count_mismatch": f"one label per point is required: {REBUILD}",
    "manifest_inconsistent": "the build metadata is stale or damaged: rebuild the tree",
    "failed_item": "the tree is incomplete: fix the cause and re-run the build",
    "layout_mismatch": "outputs keep the source's relative paths: rebuild the tree",
    "aligned_label_differs": f"aligned mode copies label files byte for byte: {REBUILD}",
    "provenance_mismatch": REBUILD,
    "copied_file_differs": "copies must be byte-identical: copy it again from the source",
    "source_changed": "the source changed since the build: rebuild or restore the source",
    "source_unreadable": "pass the source tree the output was built from",
    "missing_source_item": "the build skipped it: re-run the build",
    "extra_output_item": "the tree was built from another source, or the source lost items",
    "regenerate_failed": "pass --source and check that lads.runner is installed",
    "regenerated_differs": "processing is not reproducible here (compare lads version, "
    "libraries and device with run.json) or the tree was altered",
    "incomplete_release": "",
    "inventory_extra": "",
    "card_invalid": "regenerate it with `lads card`",
}
_SUM_LINE = re.compile(r"^([0-9a-fA-F]{64}) ([ *])(.+)$")


@dataclass(frozen=True, slots=True)
class Problem:
    """One finding: `path` relative to the output root ("." for the tree as a whole)."""

    path: str
    kind: str
    message: str


@dataclass(frozen=True)
class VerifyReport:
    """Result of `verify_tree`; `ok` when there is no problem. Notes are not problems."""

    out_root: str
    problems: list[Problem]
    files_checked: int
    bytes_hashed: int
    items: int
    source_files_checked: int = 0
    regenerated: int = 0
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def counts_by_kind(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for p in self.problems:
            counts[p.kind] = counts.get(p.kind, 0) + 1
        return dict(sorted(counts.items()))

    def to_json(self) -> str:
        payload = asdict(self) | {"ok": self.ok, "counts_by_kind": self.counts_by_kind()}
        return json.dumps(payload, indent=2, sort_keys=True) + "\n"

    def summary_text(self, max_problems: int = 50) -> str:
        mb = self.bytes_hashed / 1e6
        rate = mb / self.seconds if self.seconds > 0 else 0.0
        lines = [
            f"verify {self.out_root}: {'OK' if self.ok else 'FAILED'}",
            f"  {self.items} items; hashed {self.files_checked} output and "
            f"{self.source_files_checked} source files, {mb:.1f} MB in {self.seconds:.1f} s "
            f"({rate:.0f} MB/s); regenerated {self.regenerated} items",
        ]
        lines += [f"  note: {n}" for n in self.notes]
        if self.problems:
            lines.append(f"  {len(self.problems)} problem(s):")
            lines += [f"    {kind:<24} {n}" for kind, n in self.counts_by_kind().items()]
            lines += [f"  [{p.kind}] {p.path}: {p.message}" for p in self.problems[:max_problems]]
            if len(self.problems) > max_problems:
                lines.append(f"  ... {len(self.problems) - max_problems} more (see the JSON)")
        return "\n".join(lines)


def verify_tree(
    out_root: Path,
    source_root: Path | None,
    *,
    regenerate: int = 0,
    seed: int = 0,
    inventory: str | None = None,
    progress: bool | None = False,
    source_items: list[str] | None = None,
) -> VerifyReport:
    """Verify a built tree `out_root` (and its correspondence with `source_root`, if given).

    Args:
        out_root: the output tree (docs/output_tree.md).
        source_root: the source tree it was built from, or None to check the tree alone.
        regenerate: re-process this many random ok items (needs source_root) with
            `lads.runner.regenerate_outputs` and compare their hashes with the manifest.
        seed: seed of the random choice of regenerated items.
        inventory: expected release inventory, e.g. "semantickitti-00-10" (manifests/).
        progress: show a tqdm bar while hashing (None: only on a terminal).
        source_items: item ids of the source tree; when None they are listed with
            `lads.readers.get_reader` if available, otherwise the check is skipped (noted).

    Returns:
        VerifyReport listing every problem found.

    Raises:
        ConfigError: unknown inventory name or subset.
    """
    start = time.perf_counter()
    v = _Verifier(Path(out_root), None if source_root is None else Path(source_root), progress)
    v.run(regenerate=regenerate, seed=seed, inventory=inventory, source_items=source_items)
    return VerifyReport(
        out_root=str(out_root),
        problems=sorted(v.problems, key=lambda p: (p.path, p.kind, p.message)),
        files_checked=v.files_checked,
        bytes_hashed=v.bytes_hashed,
        items=len(v.rows),
        source_files_checked=v.source_files_checked,
        regenerated=v.regenerated,
        seconds=time.perf_counter() - start,
        notes=v.notes,
    )


def hash_files(
    paths: Iterable[Path], *, progress: bool | None = False
) -> dict[Path, str | OSError]:
    """sha256 hex digest of each file (or the OSError reading it); a thread pool of
    os.cpu_count() workers streams the files (hashlib releases the GIL while hashing)."""
    from tqdm import tqdm

    unique = list(dict.fromkeys(paths))
    out: dict[Path, str | OSError] = {}
    with (
        ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool,
        tqdm(
            total=len(unique),
            unit="file",
            disable=None if progress is None else not progress,
            desc="sha256",
        ) as bar,
    ):
        futures = {pool.submit(_sha256, p): p for p in unique}
        for fut in as_completed(futures):
            out[futures[fut]] = fut.result()
            bar.update()
    return out


def _sha256(path: Path) -> str | OSError:
    try:
        with open(path, "rb", buffering=0) as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    except OSError as exc:
        return exc


def parse_sums(text: str) -> tuple[dict[str, str], list[tuple[int, str]]]:
    """Parse GNU `sha256sum` output: "<hex>  <path>", or "<hex> *<path>" (binary mode);
    a leading backslash marks an escaped name (\\\\ and \\n).

    Returns:
        ({relpath: lowercase hex}, [(line number, what is wrong)] for unusable lines,
        absolute or `..` paths, duplicates and breaks of the bytewise sort order).
    """
    sums: dict[str, str] = {}
    bad: list[tuple[int, str]] = []
    previous = b""
    for n, line in enumerate(text.splitlines(), 1):
        escaped = line.startswith("\\")
        m = _SUM_LINE.match(line[1:] if escaped else line)
        if not m:
            bad.append((n, f"{line[:80]!r} is not '<64 hex>  <path>'"))
            continue
        path = m.group(3)
        if escaped:
            path = path.replace("\\n", "\n").replace("\\\\", "\\")
        parts = path.split("/")
        if path.startswith("/") or ".." in parts or "" in parts:
            bad.append((n, f"{path!r} is not a relative path inside the tree"))
        elif path in sums:
            bad.append((n, f"{path!r} is listed twice"))
        else:
            sums[path] = m.group(1).lower()
            if path.encode() < previous:
                bad.append((n, f"{path!r} breaks the bytewise sort order"))
            previous = path.encode()
    return sums, bad


def _regenerate_outputs() -> Any:
    """lads.runner.regenerate_outputs (the contract), else the builder's lads.worker one."""
    runner = importlib.import_module("lads.runner")
    if hasattr(runner, "regenerate_outputs"):
        return runner.regenerate_outputs
    return importlib.import_module("lads.worker").regenerate_outputs


def provenance_group(scan_relpath: str) -> str:
    """The provenance.zarr subgroup name of an item: its scan relpath, percent-quoted."""
    return quote(scan_relpath, safe="")


def _is_temp(rel: str) -> bool:
    return any(fnmatch.fnmatch(part, "*.tmp*") for part in rel.split("/"))


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _entries(row: dict[str, Any], key: str) -> list[dict[str, Any]]:
    """The well-formed {path, ...} entries of row[key] ("source" or "outputs")."""
    items = row.get(key)
    if not isinstance(items, list):
        return []
    return [e for e in items if isinstance(e, dict) and isinstance(e.get("path"), str)]


class _Verifier:
    """State of one verification; every check appends to `problems` and goes on."""

    def __init__(self, out: Path, src: Path | None, progress: bool | None) -> None:
        self.out, self.src, self.progress = out, src, progress
        self.problems: list[Problem] = []
        self.notes: list[str] = []
        self.rows: list[dict[str, Any]] = []
        self.run_json: dict[str, Any] = {}
        self.files: dict[str, int] = {}  # relpath -> size of every file in the tree
        self.sums: dict[str, str] = {}
        self.digests: dict[str, str] = {}
        self.src_digests: dict[str, str | None] = {}
        self.files_checked = self.bytes_hashed = self.source_files_checked = 0
        self.regenerated = 0

    def add(self, path: str, kind: str, what: str) -> None:
        advice = ADVICE[kind]
        self.problems.append(Problem(path, kind, f"{what}; {advice}." if advice else what))

    def run(self, *, regenerate: int, seed: int, inventory: str | None, source_items: Any) -> None:
        if not self.out.is_dir():
            self.add(".", "missing_output", f"{self.out} is not a directory")
            return
        if self.src is not None and not self.src.is_dir():
            self.add(".", "source_unreadable", f"source root {self.src} is not a directory")
            self.src = None
        self._walk()
        self._load_metadata()
        self._hash_everything()
        self._check_sums()
        self._check_run_json()
        self._check_rows()
        self._check_copied()
        self._check_provenance()
        if self.src is not None:
            self._check_sources()
            self._check_source_items(source_items)
        if regenerate > 0:
            self._check_regenerated(regenerate, seed)
        if inventory:
            self._check_inventory(inventory)
        self._check_card()

    # -- reading ------------------------------------------------------------------------
    def _walk(self) -> None:
        for dirpath, _, names in os.walk(self.out):
            for name in names:
                path = Path(dirpath, name)
                if path.is_file():
                    self.files[path.relative_to(self.out).as_posix()] = path.stat().st_size

    def _load_metadata(self) -> None:
        for rel in (SUMS, *METADATA):
            if rel not in self.files:
                self.add(rel, "missing_output", f"{rel} is missing (docs/output_tree.md)")
        if SUMS in self.files:
            self.sums, bad = parse_sums((self.out / SUMS).read_text(errors="replace"))
            for n, why in bad:
                self.add(SUMS, "sums_invalid", f"line {n}: {why}")
        if "run.json" in self.files:
            run = self._json("run.json", (self.out / "run.json").read_text(errors="replace"))
            self.run_json = run if isinstance(run, dict) else {}
        if "manifest.jsonl" in self.files:
            text = (self.out / "manifest.jsonl").read_text(errors="replace")
            for n, line in enumerate(text.splitlines(), 1):
                row = self._json(f"manifest.jsonl line {n}", line)
                if isinstance(row, dict):
                    self.rows.append(row)
                elif row is not None:
                    self.add("manifest.jsonl", "manifest_inconsistent", f"line {n}: no object")

    def _json(self, where: str, text: str) -> Any:
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            self.add(where.split(" ")[0], "manifest_inconsistent", f"{where}: bad JSON ({exc})")
            return None

    def _hash_everything(self) -> None:
        out_jobs = [self.out / rel for rel in self.sums if rel in self.files]
        src_jobs: list[Path] = []
        if self.src is not None:
            rels = [s["path"] for r in self._ok_rows() for s in _entries(r, "source")]
            rels += [c["path"] for c in self._copied()]
            src_jobs = [p for p in dict.fromkeys(self.src / r for r in rels) if p.is_file()]
        results = hash_files(out_jobs + src_jobs, progress=self.progress)
        for path in out_jobs:
            rel, digest = path.relative_to(self.out).as_posix(), results[path]
            if isinstance(digest, OSError):
                self.add(rel, "unreadable_file", f"cannot read it ({digest})")
                continue
            self.digests[rel] = digest
            self.files_checked += 1
            self.bytes_hashed += self.files[rel]
        for path in src_jobs:
            digest = results[path]
            rel = path.relative_to(self.src or path).as_posix()
            if isinstance(digest, OSError):
                self.src_digests[rel] = None
                continue
            self.src_digests[rel] = digest
            self.source_files_checked += 1
            self.bytes_hashed += path.stat().st_size

    def _ok_rows(self) -> list[dict[str, Any]]:
        ok = [r for r in self.rows if r.get("status") == "ok"]
        return [r for r in ok if isinstance(r.get("item_id"), str)]

    def _copied(self) -> list[dict[str, Any]]:
        return _entries(self.run_json, "copied_files")

    # -- the tree and its metadata ------------------------------------------------------
    def _check_sums(self) -> None:
        for rel, want in self.sums.items():
            if rel not in self.files:
                self.add(rel, "missing_output", "listed in SHA256SUMS but absent")
            elif rel in self.digests and self.digests[rel] != want:
                got = self.digests[rel]
                self.add(rel, "checksum_mismatch", f"sha256 {got}, SHA256SUMS says {want}")
        journal = [rel for rel in self.files if rel.split("/")[0] == BUILD_STATE_DIR]
        if journal:
            what = f"the build's resume journal ({len(journal)} files): the build did not finish"
            self.add(BUILD_STATE_DIR, "stray_temp_file", what)
        for rel in self.files:
            if rel in self.sums or rel in NOT_SUMMED or rel in journal:
                continue
            if _is_temp(rel):
                self.add(rel, "stray_temp_file", "a temporary file")
            else:
                self.add(rel, "extra_file", "present but not listed in SHA256SUMS")

    def _check_run_json(self) -> None:
        run = self.run_json
        if not run:
            return
        missing = [k for k in RUN_KEYS if k not in run]
        if missing:
            self.add("run.json", "manifest_inconsistent", f"keys {missing} are missing")
        failed = sum(r.get("status") == "failed" for r in self.rows)
        for key, have in (("items", len(self.rows)), ("failed", failed)):
            if key in run and run[key] != have:
                what = f"{key} is {run[key]!r} but manifest.jsonl has {have}"
                self.add("run.json", "manifest_inconsistent", what)
        if run.get("points_mode") not in ("physical", "aligned"):
            what = f"points_mode {run.get('points_mode')!r} is not 'physical' or 'aligned'"
            self.add("run.json", "manifest_inconsistent", what)

    def _check_rows(self) -> None:
        previous, unsorted_keys = "", 0
        owners: dict[str, str] = {}
        for n, row in enumerate(self.rows, 1):
            item_id = row.get("item_id")
            if not isinstance(item_id, str) or ":" not in item_id:
                what = f"line {n}: item_id {item_id!r} is not '<dataset>:<relpath>'"
                self.add("manifest.jsonl", "manifest_inconsistent", what)
                continue
            if item_id <= previous:
                how = "is listed twice" if item_id == previous else f"comes after {previous}"
                what = f"line {n}: {item_id} {how}; rows must be unique and sorted by item_id"
                self.add("manifest.jsonl", "manifest_inconsistent", what)
            previous = max(previous, item_id)
            unsorted_keys += list(row) != sorted(row)
            for out in _entries(row, "outputs"):
                if out["path"] in owners:
                    what = f"written by both {owners[out['path']]} and {item_id}"
                    self.add(out["path"], "manifest_inconsistent", what)
                owners[out["path"]] = item_id
            self._check_row(item_id, row)
        if unsorted_keys:
            what = f"{unsorted_keys} line(s) do not have sorted keys (canonical JSON)"
            self.add("manifest.jsonl", "manifest_inconsistent", what)

    def _check_row(self, item_id: str, row: dict[str, Any]) -> None:
        scan_rel = item_id.partition(":")[2]
        status, outputs = row.get("status"), _entries(row, "outputs")
        if status == "failed":
            self.add(scan_rel, "failed_item", f"{item_id} failed: {row.get('error', '?')}")
            if outputs:
                self.add(scan_rel, "manifest_inconsistent", f"failed {item_id} lists outputs")
            return
        sources = {s["path"]: s for s in _entries(row, "source")}
        if status != "ok" or not outputs or not sources:
            what = f"{item_id}: status {status!r}, {len(outputs)} outputs, {len(sources)} sources"
            self.add(scan_rel, "manifest_inconsistent", what + " (need 'ok' and both)")
            return
        for out in outputs:
            self._check_output(item_id, out, sources)
        scans = [o for o in outputs if o.get("role") == "scan"]
        if len(scans) != 1 or scans[0]["path"] != scan_rel or scan_rel not in sources:
            what = f"{item_id}: the scan output must be the source scan's own relative path"
            self.add(scan_rel, "layout_mismatch", f"{what}, got {[o['path'] for o in scans]}")
        counted = [o for o in outputs if _count(o.get("records"))]
        if scans and _count(scans[0].get("records")):
            for out in counted:
                if out["records"] != scans[0]["records"]:
                    what = (
                        f"{item_id}: {out.get('role')} holds {out['records']} records but "
                        f"the scan {scans[0]['path']} holds {scans[0]['records']} points"
                    )
                    self.add(out["path"], "label_count_mismatch", what)
        self._check_points(item_id, row, scans[0] if len(scans) == 1 else None, sources)

    def _check_output(self, item_id: str, out: dict[str, Any], sources: dict[str, Any]) -> None:
        rel = out["path"]
        numbers = ("bytes", "records", "record_bytes")
        if any(k not in out for k in OUTPUT_KEYS) or not all(_count(out[k]) for k in numbers):
            what = f"{item_id}: an output needs {OUTPUT_KEYS} (counts >= 0), got {out}"
            self.add(rel, "manifest_inconsistent", what)
            return
        if rel not in sources:
            what = f"{item_id}: not at the relative path of a source file ({sorted(sources)})"
            self.add(rel, "layout_mismatch", what)
        size = self.files.get(rel)
        if size is not None and size != out["bytes"]:
            self.add(rel, "size_mismatch", f"{size} bytes, the manifest says {out['bytes']}")
        elif size is None and rel not in self.sums:
            self.add(rel, "missing_output", f"output of {item_id} is absent")
        if self.sums.get(rel) != out["sha256"]:
            what = f"manifest sha256 {out['sha256']}, SHA256SUMS {self.sums.get(rel)}"
            self.add(rel, "manifest_inconsistent", what)
        rb = out["record_bytes"]
        if rb > 0 and out["records"] * rb != out["bytes"]:
            what = f"{out['records']} records x {rb} bytes != {out['bytes']} bytes (manifest)"
            self.add(rel, "record_count_mismatch", what)
        elif rb > 0 and size is not None and size % rb:
            what = f"{size} bytes is not a whole number of {rb}-byte records"
            self.add(rel, "record_count_mismatch", what)

    def _check_points(
        self, item_id: str, row: dict[str, Any], scan: dict[str, Any] | None, sources: Any
    ) -> None:
        where, pts = item_id.partition(":")[2], row.get("points")
        if not isinstance(pts, dict) or not all(_count(pts.get(k)) for k in POINT_KEYS):
            self.add(where, "manifest_inconsistent", f"{item_id}: points {pts!r} lacks counts")
            return
        s, o, lost = pts["source"], pts["output"], pts["lost"]
        returned = pts["kept"] + pts["attenuated"] + pts["particle"]
        mode = self.run_json.get("points_mode")
        rules = [("output == scan records", scan is None or o == scan.get("records"))]
        if mode == "physical":
            rules += [("kept+attenuated+particle == output", returned == o)]
            rules += [("output + lost == source", o + lost == s)]
        elif mode == "aligned":
            rules += [("output == source", o == s)]
            rules += [("kept+attenuated+particle+lost == source", returned + lost == s)]
        rb = scan.get("record_bytes", 0) if scan else 0
        src_scan = sources.get(scan["path"], {}) if scan else {}
        if rb and _count(src_scan.get("bytes")):
            rules += [("source bytes == source x record_bytes", src_scan["bytes"] == s * rb)]
        for rule, holds in rules:
            if not holds:
                what = f"{item_id} ({mode} mode): {rule} fails for points {pts}"
                self.add(where, "manifest_inconsistent", what)
        for out in _entries(row, "outputs") if mode == "aligned" else ():
            src = sources.get(out["path"])
            if out.get("role") != "scan" and src and src.get("sha256") != out.get("sha256"):
                self.add(out["path"], "aligned_label_differs", f"{item_id}: differs from source")

    def _check_copied(self) -> None:
        outputs = {o["path"] for r in self.rows for o in _entries(r, "outputs")}
        for entry in self._copied():
            rel = entry["path"]
            if rel in outputs:
                self.add(rel, "manifest_inconsistent", "both a copied file and an item output")
            if rel not in self.files:
                if rel not in self.sums:
                    self.add(rel, "missing_output", "copied file (run.json) is absent")
                continue
            if self.files[rel] != entry.get("bytes"):
                what = f"{self.files[rel]} bytes, run.json says {entry.get('bytes')}"
                self.add(rel, "size_mismatch", what)
            if self.sums.get(rel) != entry.get("sha256"):
                what = f"run.json sha256 {entry.get('sha256')}, SHA256SUMS {self.sums.get(rel)}"
                self.add(rel, "manifest_inconsistent", what)
            if self.src is not None:
                src = self.src_digests.get(rel)
                if src is None or src != self.digests.get(rel):
                    why = "absent or unreadable in" if src is None else "different from"
                    self.add(rel, "copied_file_differs", f"{why} the source {self.src / rel}")

    def _check_provenance(self) -> None:
        root = self._zarr_json("provenance.zarr/zarr.json")
        if root is None:
            return
        attrs = root.get("attributes") or {}
        for key in ("points_mode", "config_hash"):
            if key in self.run_json and attrs.get(key) != self.run_json[key]:
                what = f"attribute {key} is {attrs.get(key)!r}, run.json {self.run_json[key]!r}"
                self.add("provenance.zarr", "provenance_mismatch", what)
        for row in self._ok_rows():
            scan_rel = row["item_id"].partition(":")[2]
            group = f"provenance.zarr/{provenance_group(scan_rel)}"
            pts = row["points"] if isinstance(row.get("points"), dict) else {}
            want = {"item_id": row["item_id"], "relpath": scan_rel}
            want |= {"n_source": pts.get("source"), "n_output": pts.get("output")}
            meta = self._zarr_json(f"{group}/zarr.json")
            got = {k: (meta or {}).get("attributes", {}).get(k) for k in want}
            if meta is not None and got != want:
                self.add(group, "provenance_mismatch", f"attributes {got}, manifest {want}")
            for array in ("source_index", "outcome"):
                meta = self._zarr_json(f"{group}/{array}/zarr.json")
                if meta is not None and meta.get("shape") != [pts.get("output")]:
                    what = f"shape {meta.get('shape')}, expected [{pts.get('output')}]"
                    self.add(f"{group}/{array}", "provenance_mismatch", what)

    def _zarr_json(self, rel: str) -> dict[str, Any] | None:
        if rel not in self.files:
            if rel != "provenance.zarr/zarr.json" and "provenance.zarr/zarr.json" in self.files:
                self.add(rel, "provenance_mismatch", "missing (one group per ok item)")
            return None
        try:
            meta = json.loads((self.out / rel).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            self.add(rel, "provenance_mismatch", f"unreadable zarr metadata ({exc})")
            return None
        return meta if isinstance(meta, dict) else {}

    # -- against the source -------------------------------------------------------------
    def _check_sources(self) -> None:
        for row in self._ok_rows():
            for s in _entries(row, "source"):
                got = self.src_digests.get(s["path"])
                if got != s.get("sha256"):
                    why = "is absent or unreadable" if got is None else f"has sha256 {got}"
                    what = f"source of {row['item_id']} {why}; the build saw {s.get('sha256')}"
                    self.add(s["path"], "source_changed", what)

    def _check_source_items(self, source_items: list[str] | None) -> None:
        if source_items is None:
            source_items = self._list_source_items()
            if source_items is None:
                return
        have = {r["item_id"] for r in self.rows if isinstance(r.get("item_id"), str)}
        want = set(source_items)
        for item in sorted(want - have):
            what = f"source item {item} has no row in manifest.jsonl"
            self.add(item.partition(":")[2], "missing_source_item", what)
        for item in sorted(have - want):
            self.add(item.partition(":")[2], "extra_output_item", f"{item} is not in the source")

    def _list_source_items(self) -> list[str] | None:
        name = self.run_json.get("source")
        try:
            get_reader = importlib.import_module("lads.readers").get_reader
        except (ImportError, AttributeError) as exc:
            self.notes.append(
                f"source item correspondence not checked: lads.readers.get_reader is not "
                f"available ({exc}); pass source_items to check it"
            )
            return None
        if not isinstance(name, str):
            self.notes.append("source item correspondence not checked: run.json names no reader")
            return None
        options = self.run_json.get("reader_options") or {}
        try:
            reader = get_reader(name, self.src, **(options if isinstance(options, dict) else {}))
            self._check_copied_list(reader)
            return [it.item_id for it in reader.items()]
        except LadsError as exc:
            self.add(".", "source_unreadable", f"reader {name!r} cannot list the source: {exc}")
            return None

    def _check_copied_list(self, reader: Any) -> None:
        listed = {c["path"] for c in self._copied()}
        for rel in sorted(set(reader.copied_files()) - listed):
            self.add(rel, "missing_output", "a file to copy from the source is not in the tree")

    def _check_regenerated(self, k: int, seed: int) -> None:
        rows = sorted(self._ok_rows(), key=lambda r: r["item_id"])
        if self.src is None or not rows:
            self.add(".", "regenerate_failed", f"--regenerate {k} needs a source and ok items")
            return
        picks = np.random.default_rng(seed).choice(len(rows), size=min(k, len(rows)), replace=False)
        chosen = [rows[i] for i in sorted(int(i) for i in picks)]
        ids = [r["item_id"] for r in chosen]
        try:
            got = _regenerate_outputs()(self.out, self.src, ids)
        except (ImportError, AttributeError, LadsError) as exc:
            self.add(".", "regenerate_failed", f"cannot regenerate {ids}: {exc}")
            return
        self.regenerated = len(ids)
        for row in chosen:
            want = {o["path"]: o.get("sha256") for o in _entries(row, "outputs")}
            have = got.get(row["item_id"], {})
            for path in sorted(set(want) | set(have)):
                if want.get(path) != have.get(path):
                    what = (
                        f"{row['item_id']}: regenerated {have.get(path)}, manifest {want.get(path)}"
                    )
                    self.add(path, "regenerated_differs", what)

    def _check_inventory(self, release: str) -> None:
        from lads import inventory as inv

        name, subset = inv.parse_release(release)
        rows = self._ok_rows()
        version = inv.tree_version(
            self.run_json, [o["path"] for r in rows for o in _entries(r, "outputs")]
        )
        for path, kind, message in inv.compare(
            [r["item_id"] for r in rows], name, subset, version=version
        ):
            self.add(path, kind, message)
        self.notes.extend(inv.notes(name, subset))

    def _check_card(self) -> None:
        if "README.md" not in self.files:
            self.notes.append("no dataset card (README.md); `lads card` writes one")
            return
        from lads.card import validate_card

        for msg in validate_card((self.out / "README.md").read_text(errors="replace")):
            self.add("README.md", "card_invalid", msg)
