"""`lads verify`: check a built variant tree against docs/output_tree.md and its source.

Every problem is reported, never only the first: (1) SHA256SUMS against the files on disk;
(2) manifest.jsonl against itself, SHA256SUMS, run.json and the file sizes; (3) the
provenance store's per-item metadata; (4) with a source root, the one-to-one correspondence
of items and files with the source; (5) optionally K regenerated items; (6) the expected
inventory of a release; (7) the dataset card's front matter. `ADVICE` lists every problem
kind with what to do about it.

Modules: `report` (Problem, VerifyReport, ADVICE), `state` (one verification's state),
`hashing` (SHA256SUMS), `manifest_checks` (run.json, manifest.jsonl), `provenance`
(provenance.zarr), `source_checks` (source tree, regeneration, inventory), `tree`
(verify_tree, the order of the checks).
"""

from __future__ import annotations

from lads.verify.hashing import BUILD_STATE_DIR, NOT_SUMMED, SUMS, hash_files, parse_sums
from lads.verify.manifest_checks import METADATA, OUTPUT_KEYS, POINT_KEYS, RUN_KEYS
from lads.verify.provenance import provenance_group
from lads.verify.report import ADVICE, REBUILD, Problem, VerifyReport
from lads.verify.tree import verify_tree

__all__ = [
    "ADVICE",
    "BUILD_STATE_DIR",
    "METADATA",
    "NOT_SUMMED",
    "OUTPUT_KEYS",
    "POINT_KEYS",
    "REBUILD",
    "RUN_KEYS",
    "SUMS",
    "Problem",
    "VerifyReport",
    "hash_files",
    "parse_sums",
    "provenance_group",
    "verify_tree",
]
