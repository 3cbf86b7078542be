"""The state of one verification: what was read from the tree, what was hashed, and every
problem found so far (the checks add to it and go on)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from lads.verify.report import ADVICE, Problem


class Verifier:
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
        self.holds_lock = False  # this verification holds the tree's lock (--regenerate)

    def add(self, path: str, kind: str, what: str) -> None:
        advice = ADVICE[kind]
        self.problems.append(Problem(path, kind, f"{what}; {advice}." if advice else what))

    def walk(self) -> None:
        """Record the size of every file in the tree."""
        for dirpath, _, names in os.walk(self.out):
            for name in names:
                path = Path(dirpath, name)
                if path.is_file():
                    self.files[path.relative_to(self.out).as_posix()] = path.stat().st_size

    def ok_rows(self) -> list[dict[str, Any]]:
        ok = [r for r in self.rows if r.get("status") == "ok"]
        return [r for r in ok if isinstance(r.get("item_id"), str)]

    def copied(self) -> list[dict[str, Any]]:
        return entries(self.run_json, "copied_files")


def count(value: Any) -> bool:
    """Whether `value` is a count: an int >= 0 (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def entries(row: dict[str, Any], key: str) -> list[dict[str, Any]]:
    """The well-formed {path, ...} entries of row[key] ("source" or "outputs")."""
    items = row.get(key)
    if not isinstance(items, list):
        return []
    return [e for e in items if isinstance(e, dict) and isinstance(e.get("path"), str)]
