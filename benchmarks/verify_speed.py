"""MB/s of `lads verify` on a ~400 MB synthetic tree of 2 MB scan files (target >= 200 MB/s).

Builds, in a temporary directory, a source tree and its variant tree in the exact layout of
docs/output_tree.md (the fake-tree writer of tests/fake_trees.py: random bytes,
manifest.jsonl, run.json, provenance.zarr, SHA256SUMS), then times `verify_tree` on the
tree alone and against its source, and `sha256sum -c` (one core) for comparison. The files
were just written, so they are read from the page cache: this measures hashing and
bookkeeping, not the disk.

Run: .venv/bin/python -m benchmarks.verify_speed   (writes benchmarks/results/verify.json)
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import machine_info, write_result
from lads.verify import verify_tree
from tests.fake_trees import build_fake_tree

N_ITEMS = 160  # 160 x (2 MB scan + 0.5 MB label) = 400 MB per tree
SCAN_POINTS = 131_072  # x 16 bytes = 2 MiB per scan
TARGET_MB_S = 200.0


def _timed_verify(out: Path, src: Path | None) -> dict[str, Any]:
    start = time.perf_counter()
    report = verify_tree(out, src)
    seconds = time.perf_counter() - start
    return {
        "ok": report.ok,
        "problems": len(report.problems),
        "files_hashed": report.files_checked + report.source_files_checked,
        "mb_hashed": round(report.bytes_hashed / 1e6, 1),
        "seconds": round(seconds, 3),
        "mb_per_s": round(report.bytes_hashed / 1e6 / seconds, 1),
    }


def _timed_sha256sum(out: Path) -> dict[str, Any] | None:
    if shutil.which("sha256sum") is None:
        return None
    start = time.perf_counter()
    done = subprocess.run(["sha256sum", "--quiet", "-c", "SHA256SUMS"], cwd=out, check=False)
    seconds = time.perf_counter() - start
    mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    return {
        "ok": done.returncode == 0,
        "seconds": round(seconds, 3),
        "mb_per_s": round(mb / seconds, 1),
    }


def main() -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="lads-verify-bench-") as tmp:
        start = time.perf_counter()
        src, out = build_fake_tree(Path(tmp), n_items=N_ITEMS, points_base=SCAN_POINTS, card=True)
        build_s = time.perf_counter() - start
        _timed_verify(out, None)  # warm-up: imports, page cache
        tree_only = _timed_verify(out, None)
        with_source = _timed_verify(out, src)
        coreutils = _timed_sha256sum(out)
    result = {
        "what": "lads.verify.verify_tree on a synthetic tree of 2 MB scans (warm page cache)",
        "items": N_ITEMS,
        "tree_write_seconds": round(build_s, 1),
        "tree_only": tree_only,
        "against_source": with_source,
        "sha256sum_c_one_core": coreutils,
        "target_mb_per_s": TARGET_MB_S,
        "meets_target": tree_only["mb_per_s"] >= TARGET_MB_S
        and with_source["mb_per_s"] >= TARGET_MB_S,
        "machine": machine_info(),
    }
    path = write_result("verify.json", result)
    sys.stdout.write(
        f"verify: tree {tree_only['mb_per_s']} MB/s, with source {with_source['mb_per_s']} MB/s"
        f" (sha256sum -c: {coreutils and coreutils['mb_per_s']} MB/s) -> {path}\n"
    )
    return result


if __name__ == "__main__":
    main()
