"""SHA256SUMS: hashing files in parallel, parsing GNU `sha256sum` output, and checking the
tree's files against it (missing, changed, unlisted and leftover temporary files)."""

from __future__ import annotations

import fnmatch
import hashlib
import os
import re
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from lads.built_tree import NOT_SUMMED, SHA256SUMS, STATE_DIR
from lads.card import CARD_NAME
from lads.files import TMP_SUFFIX
from lads.verify.state import Verifier, entries

SUMS = SHA256SUMS  # the names verify has always exported
BUILD_STATE_DIR = STATE_DIR
_SUM_LINE = re.compile(r"^([0-9a-fA-F]{64}) ([ *])(.+)$")


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


def hash_everything(v: Verifier) -> None:
    """Hash, in one pool, the listed output files and the source files the manifest and
    run.json name; fills v.digests and v.src_digests (None: unreadable in the source)."""
    out_jobs = [v.out / rel for rel in v.sums if rel in v.files]
    src_jobs: list[Path] = []
    if v.src is not None:
        rels = [s["path"] for r in v.ok_rows() for s in entries(r, "source")]
        rels += [c["path"] for c in v.copied()]
        src_jobs = [p for p in dict.fromkeys(v.src / r for r in rels) if p.is_file()]
    results = hash_files(out_jobs + src_jobs, progress=v.progress)
    for path in out_jobs:
        rel, digest = path.relative_to(v.out).as_posix(), results[path]
        if isinstance(digest, OSError):
            v.add(rel, "unreadable_file", f"cannot read it ({digest})")
            continue
        v.digests[rel] = digest
        v.files_checked += 1
        v.bytes_hashed += v.files[rel]
    for path in src_jobs:
        digest = results[path]
        rel = path.relative_to(v.src or path).as_posix()
        if isinstance(digest, OSError):
            v.src_digests[rel] = None
            continue
        v.src_digests[rel] = digest
        v.source_files_checked += 1
        v.bytes_hashed += path.stat().st_size


def check_sums(v: Verifier) -> None:
    """Every listed file is present with its digest; every other file is reported."""
    for rel, want in v.sums.items():
        # The card is rendered from the tree's metadata: `lads card` remakes it.
        kind = "card_invalid" if rel == CARD_NAME else None
        if rel not in v.files:
            v.add(rel, kind or "missing_output", "listed in SHA256SUMS but absent")
        elif rel in v.digests and v.digests[rel] != want:
            got = v.digests[rel]
            v.add(rel, kind or "checksum_mismatch", f"sha256 {got}, SHA256SUMS says {want}")
    journal = [rel for rel in v.files if rel.split("/")[0] == BUILD_STATE_DIR]
    if journal:
        what = f"the build's resume journal ({len(journal)} files): the build did not finish"
        v.add(BUILD_STATE_DIR, "stray_temp_file", what)
    for rel in v.files:
        if rel in v.sums or rel in NOT_SUMMED or rel in journal:
            continue
        if _is_temp(rel):
            v.add(rel, "stray_temp_file", "a temporary file")
        else:
            v.add(rel, "extra_file", "present but not listed in SHA256SUMS")


def _is_temp(rel: str) -> bool:
    """A temp file of lads' atomic writes (`*.lads-tmp`) or of a tool's (`*.tmp*`)."""
    return rel.endswith(TMP_SUFFIX) or any(
        fnmatch.fnmatch(part, "*.tmp*") for part in rel.split("/")
    )
