"""What an earlier run of a build left that is still good: the items whose outputs, provenance
and sources are intact on disk, so a killed or repeated build redoes only the rest."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lads import provenance
from lads.built_tree import MANIFEST, SHA256SUMS, state_path
from lads.files import sha256_file
from lads.frame import Item


def json_lines(path: Path) -> list[dict[str, Any]]:
    """The JSON objects of a JSON-lines file; damaged lines (a torn or edited file) are
    skipped, so their items are rebuilt."""
    out: list[dict[str, Any]] = []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError):
        return out
    for line in text.splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict) and isinstance(row.get("item_id"), str):
            out.append(row)
    return out


def recorded_versions(row: dict[str, Any]) -> list[tuple[str, str]]:
    """(name, version) of each stage a manifest row says built the item."""
    stages = row.get("stages")
    if not isinstance(stages, list):
        return []
    return [(str(s.get("name")), str(s.get("version"))) for s in stages if isinstance(s, dict)]


def finished_rows(
    out_root: Path,
    source_root: Path,
    items: list[Item],
    stage_versions: list[tuple[str, str]] | None = None,
) -> dict[str, dict[str, Any]]:
    """Rows of items already built whose every artefact is still intact on disk: each
    output file (size and sha256), the provenance group (`provenance.item_intact`, against
    the SHA256SUMS of an earlier finished run when there is one), and the source files the
    item was built from (unchanged since); with `stage_versions` ((name, version) of each
    stage of this build), also built by those stage versions: an item an older lads built
    with other bytes is rebuilt rather than mixed into the tree. Anything else is rebuilt,
    so a rerun repairs whatever damage it finds and follows a source that changed."""
    rows = {r["item_id"]: r for r in json_lines(out_root / MANIFEST)}
    for item in items:
        for row in json_lines(state_path(out_root, item.item_id)):
            rows[item.item_id] = row
    listed = listed_sums(out_root / SHA256SUMS)
    # A window's scans and the pose files are sources of many rows: hashed once each.
    seen: dict[tuple[Path, int, int], str] = {}
    intact = {}
    wanted = {i.item_id for i in items}
    for item_id, row in rows.items():
        if (
            item_id in wanted
            and row.get("status") == "ok"
            and (stage_versions is None or recorded_versions(row) == stage_versions)
            and files_intact(out_root, row.get("outputs"))
            and files_intact(source_root, row.get("source"), seen)
            and provenance.item_intact(out_root, row, listed)
        ):
            intact[item_id] = row
    return intact


def listed_sums(path: Path) -> dict[str, str]:
    """relpath -> sha256 of a SHA256SUMS file ({} when absent or unreadable)."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError):
        return {}
    return {line[66:]: line[:64] for line in lines if len(line) > 66 and line[64:66] == "  "}


def files_intact(
    root: Path, entries: Any, seen: dict[tuple[Path, int, int], str] | None = None
) -> bool:
    """Whether every {path, bytes, sha256} entry (a row's outputs or sources) is on disk
    under `root` with that size and digest; `seen` keeps digests by (path, size, mtime) for
    files that many rows name."""
    if not isinstance(entries, list) or not entries:
        return False
    try:
        for entry in entries:
            path = root / entry["path"]
            if not path.is_file():
                return False
            stat = path.stat()
            if stat.st_size != entry["bytes"]:
                return False
            key = (path, stat.st_size, stat.st_mtime_ns)
            digest = seen.get(key) if seen is not None else None
            if digest is None:
                digest = sha256_file(path)
                if seen is not None:
                    seen[key] = digest
            if digest != entry["sha256"]:
                return False
    except (OSError, KeyError, TypeError):
        return False
    return True
