"""What `lads verify` reports: one `Problem` per finding, the `VerifyReport` of a tree, and
`ADVICE`, what to do about each problem kind."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

REBUILD = "rebuild the item (lads build resumes) or restore the file from the release"
ADVICE = {
    "missing_output": REBUILD,
    "extra_file": "lads did not write it: move it out of the tree (a rebuild never adds a "
    "file it did not write to SHA256SUMS)",
    "stray_temp_file": "an interrupted run left it: re-run the build (it removes them)",
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
    "copied_file_differs": "copies must be byte-identical: if the source changed, re-run the "
    "build (it copies the file again and rebuilds the items it feeds); if the source lost it, "
    "verify against the source the tree was built from; else restore the tree's copy",
    "source_changed": "the source changed since the build: rebuild or restore the source",
    "source_unreadable": "pass the source tree the output was built from",
    "missing_source_item": "the build skipped it: re-run the build",
    "extra_output_item": "the tree was built from another source, or the source lost items",
    "regenerate_no_source": "pass the source tree it was built from (--against)",
    "regenerate_nothing_built": "no item was built, so none can be rebuilt: fix the failed "
    "items' cause and re-run the build",
    "regenerate_failed": "the rebuild itself failed: see the message (an installed lads "
    "provides lads.worker)",
    "regenerated_differs": "processing is not reproducible here (compare lads version, "
    "libraries and device with run.json) or the tree was altered",
    "incomplete_release": "",
    "inventory_extra": "",
    "card_invalid": "regenerate it with `lads card`",
    "build_running": "verify the tree when that build has finished",
    "inventory_other_dataset": "pass the inventory of the tree's own dataset (manifests/)",
}


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
