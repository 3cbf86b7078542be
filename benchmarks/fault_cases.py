"""The faults of the fault-injection campaign (benchmarks/faults.py, tests/integration/
test_faults.py): what each one breaks, and what "nothing lost" means for it.

Every fault runs against a `Bench`: a source tree, a reference build of it (uninterrupted,
on a clean output) and a scratch folder. A fault is *caught* when lads says so in words (a
failed item naming the file, a refusal naming the cause, a verify problem) and *survives*
when, after the remedy a user would apply (rerun the same build, restore the source file,
move a foreign file out, free space), the tree verifies and is byte-identical to the
reference. Anything else is a loss.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lads.config import pipeline_for
from lads.errors import LadsError
from lads.runner import BuildReport, run_build
from lads.verify import verify_tree

SCAN = "sequences/00/velodyne/000001.bin"
LABEL = "sequences/00/labels/000001.label"
ITEM = f"semantickitti:{SCAN}"


@dataclass
class Result:
    fault: str
    cls: str
    caught: bool
    survived: bool
    detail: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "fault": self.fault,
            "class": self.cls,
            "caught": self.caught,
            "survived": self.survived,
            "detail": self.detail[:400],
        }


@dataclass
class Bench:
    """A source tree, its reference build and a scratch folder for one campaign."""

    source: Path
    work: Path
    variant: str = "rain"

    def __post_init__(self) -> None:
        self.reference = self.work / "reference"
        shutil.rmtree(self.reference, ignore_errors=True)
        report = self.build(self.source, self.reference)
        if not isinstance(report, BuildReport) or not report.complete:
            raise RuntimeError(f"reference build failed: {report}")
        self.sums = (self.reference / "SHA256SUMS").read_text()
        self.count = 0

    def scratch(self, name: str) -> Path:
        self.count += 1
        path = self.work / f"{self.count:03d}-{name}"
        shutil.rmtree(path, ignore_errors=True)
        return path

    def build(self, src: Path, out: Path, **kw: Any) -> BuildReport | LadsError:
        pipeline = pipeline_for("semantickitti", self.variant)
        try:
            return run_build("semantickitti", src, out, pipeline, progress=False, **kw)
        except LadsError as exc:
            return exc

    def identical(self, out: Path, src: Path | None = None) -> tuple[bool, str]:
        """The tree verifies against its source and equals the reference byte for byte
        (run.json and the card name the source's path, so a copy of the source changes
        those two files only)."""
        check = verify_tree(out, src or self.source)
        if not check.ok:
            return False, "; ".join(f"{p.kind} {p.path}" for p in check.problems[:5])
        if _comparable(out / "SHA256SUMS", src is not None) != _comparable(
            self.reference / "SHA256SUMS", src is not None
        ):
            return False, "verifies, but differs from the reference build"
        return True, "verifies and equals the reference"

    def copy_source(self, name: str) -> Path:
        dst = self.scratch(name)
        shutil.copytree(self.source, dst, symlinks=True)
        return dst

    def copy_reference(self, name: str) -> Path:
        dst = self.scratch(name)
        shutil.copytree(self.reference, dst)
        return dst


def listed_items(bench: Bench) -> list[str]:
    """Item ids of the reference build."""
    return [
        json.loads(line)["item_id"]
        for line in (bench.reference / "manifest.jsonl").read_text().splitlines()
    ]


def _comparable(sums: Path, other_source: bool) -> list[str]:
    lines = sums.read_text().splitlines()
    if not other_source:
        return lines
    return [line for line in lines if line[66:] not in ("run.json", "README.md")]


def _complete(report: BuildReport | LadsError) -> bool:
    return isinstance(report, BuildReport) and report.complete


# --- bad source entries: a name the layout implies that cannot be built ------------------


def _break_entry(path: Path, how: str) -> None:
    path.unlink()
    if how == "directory":
        path.mkdir()
    elif how == "dangling_symlink":
        path.symlink_to(path.with_name("gone.bin"))
    elif how == "self_loop":
        path.symlink_to(path.name)
    elif how == "two_link_loop":
        path.with_name("loop.bin").symlink_to(path.name)
        path.symlink_to("loop.bin")
    elif how == "empty_file":
        path.write_bytes(b"")


def _corrupt_points(src: Path, how: str) -> None:
    scan, label = src / SCAN, src / LABEL
    points = np.fromfile(scan, dtype="<f4").reshape(-1, 4)
    data = scan.read_bytes()
    scan.unlink()
    label_data = label.read_bytes()
    if how == "truncated_3_bytes":
        scan.write_bytes(data[:-3])
    elif how == "nan_coordinate":
        points[7, 0] = np.nan
        scan.write_bytes(points.tobytes())
    elif how == "absurd_coordinate":
        points[7, 1] = 1e30
        scan.write_bytes(points.tobytes())
    else:
        scan.write_bytes(data)
        label.unlink()
        if how == "label_count_mismatch":
            label.write_bytes(label_data[:-8])


ENTRY_KINDS = ("directory", "dangling_symlink", "self_loop", "two_link_loop", "empty_file")
POINT_KINDS = ("truncated_3_bytes", "nan_coordinate", "absurd_coordinate",
               "label_count_mismatch", "missing_label")  # fmt: skip


def bad_entry(bench: Bench, kind: str) -> Result:
    src = bench.copy_source(f"src-{kind}")
    if kind in ENTRY_KINDS:
        _break_entry(src / SCAN, kind)
    else:
        _corrupt_points(src, kind)
    out = bench.scratch(f"out-{kind}")
    first = bench.build(src, out)
    failed = dict(first.failed) if isinstance(first, BuildReport) else {}
    named = ITEM in failed and str(src / SCAN.rsplit("/", 1)[0]) in failed[ITEM]
    others = isinstance(first, BuildReport) and first.built == first.items - len(failed)
    check = verify_tree(out, src)
    seen = any(p.kind == "failed_item" and p.path == SCAN for p in check.problems)
    # the remedy: restore the frame from the archive (the reference source here)
    for extra in ("loop.bin",):
        (src / SCAN).with_name(extra).unlink(missing_ok=True)
    for rel in (SCAN, LABEL):
        target = src / rel
        if target.is_dir() and not target.is_symlink():
            target.rmdir()
        elif target.is_symlink() or target.exists():
            target.unlink()
        shutil.copy2(bench.source / rel, target)
    second = bench.build(src, out)
    ok, why = bench.identical(out, src)
    caught = named and others and seen
    detail = f"{failed.get(ITEM, repr(first))[:200]} | after restoring: {why}"
    return Result(kind, "bad_entry", caught, caught and _complete(second) and ok, detail)


# --- damage to a finished tree: a rerun must repair it --------------------------------


def _flip(path: Path, offset: int = 100) -> None:
    data = bytearray(path.read_bytes())
    data[min(offset, len(data) - 1)] ^= 0xFF
    path.write_bytes(bytes(data))


def _provenance_chunk(out: Path) -> Path:
    group = out / "provenance.zarr" / SCAN.replace("/", "%2F")
    return sorted(
        p for p in (group / "source_index").rglob("*") if p.is_file() and p.name != "zarr.json"
    )[0]


def _swap(a: Path, b: Path) -> None:
    tmp = a.with_name("swap.tmp-file")
    a.rename(tmp)
    b.rename(a)
    tmp.rename(b)


DAMAGE: dict[str, Callable[[Path], None]] = {
    "scan_deleted": lambda o: (o / SCAN).unlink(),
    "label_truncated_16": lambda o: (o / LABEL).write_bytes((o / LABEL).read_bytes()[:-16]),
    "scan_byte_flipped": lambda o: _flip(o / SCAN),
    "label_byte_flipped": lambda o: _flip(o / LABEL),
    "scans_swapped": lambda o: _swap(o / SCAN, o / "sequences/00/velodyne/000002.bin"),
    "manifest_deleted": lambda o: (o / "manifest.jsonl").unlink(),
    "manifest_byte_flipped": lambda o: _flip(o / "manifest.jsonl", 40),
    "sums_deleted": lambda o: (o / "SHA256SUMS").unlink(),
    "sums_byte_flipped": lambda o: _flip(o / "SHA256SUMS", 10),
    "card_deleted": lambda o: (o / "README.md").unlink(),
    "provenance_group_deleted": lambda o: shutil.rmtree(
        o / "provenance.zarr" / SCAN.replace("/", "%2F")
    ),
    "provenance_chunk_flipped": lambda o: _flip(_provenance_chunk(o), 5),
    "provenance_root_deleted": lambda o: (o / "provenance.zarr" / "zarr.json").unlink(),
    "copied_file_changed": lambda o: (o / "sequences/00/calib.txt").write_text("P0: 0\n"),
    "stray_temp_file": lambda o: (o / f"{SCAN}.123-abcd.lads-tmp").write_bytes(b"x"),
    "stale_journal": lambda o: _stale_journal(o),
}


def _stale_journal(out: Path) -> None:
    """A journal record claiming an item is done, over outputs that are not its own."""
    from lads.built_tree import state_path

    _flip(out / SCAN)
    rows = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    path = state_path(out, ITEM)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(next(r for r in rows if r["item_id"] == ITEM)))


def damage(bench: Bench, kind: str) -> Result:
    out = bench.copy_reference(f"damage-{kind}")
    DAMAGE[kind](out)
    check = verify_tree(out, bench.source)
    caught = not check.ok
    report = bench.build(bench.source, out)
    ok, why = bench.identical(out)
    said = "; ".join(f"{p.kind} {p.path}" for p in check.problems[:3])
    return Result(
        kind, "damage", caught, _complete(report) and ok, f"verify: {said} | rerun: {why}"
    )


def foreign_file(bench: Bench) -> Result:
    """A file of the user's in a finished tree: reported, never summed; gone, all is well."""
    out = bench.copy_reference("foreign")
    (out / "my_notes.txt").write_text("mine\n")
    report = bench.build(bench.source, out)
    caught = isinstance(report, BuildReport) and report.foreign == ["my_notes.txt"]
    kept = (out / "my_notes.txt").read_text() == "mine\n"
    unsummed = "my_notes.txt" not in (out / "SHA256SUMS").read_text()
    (out / "my_notes.txt").unlink()  # the remedy: move it out of the tree
    second = bench.build(bench.source, out)
    ok, why = bench.identical(out)
    survived = caught and kept and unsummed and _complete(second) and ok
    return Result(
        "foreign_file",
        "damage",
        caught,
        survived,
        f"reported {getattr(report, 'foreign', report)}; {why}",
    )


def source_changed(bench: Bench) -> Result:
    """A source frame replaced after the build (a fixed or re-extracted file): verify says
    so, and a rerun rebuilds that item to what a fresh build of the new source gives."""
    src = bench.copy_source("changed-src")
    out = bench.scratch("changed-out")
    bench.build(src, out)
    scan, label = src / SCAN, src / LABEL
    points, labels = np.fromfile(scan, "<f4"), np.fromfile(label, "<u4")
    for path, data in ((scan, points[:-4]), (label, labels[:-1])):  # one point fewer
        path.unlink()
        path.write_bytes(data.tobytes())
    check = verify_tree(out, src)
    caught = any(p.kind == "source_changed" for p in check.problems)
    report = bench.build(src, out)
    fresh = bench.scratch("changed-fresh")
    bench.build(src, fresh)
    ok = verify_tree(out, src).ok
    same = (out / "SHA256SUMS").read_text() == (fresh / "SHA256SUMS").read_text()
    detail = f"verify: {[p.kind for p in check.problems][:3]}; rebuilt equals fresh: {same}"
    return Result("source_changed", "damage", caught, _complete(report) and ok and same, detail)


def run_json(bench: Bench, kind: str) -> Result:
    """OUT/run.json that is not lads': a named refusal that changes nothing."""
    out = bench.copy_reference(f"run-json-{kind}")
    text = "not json {" if kind == "run_json_not_json" else '{"app": "someone else"}\n'
    (out / "run.json").write_text(text)
    before = sorted((p.relative_to(out).as_posix(), p.stat().st_size) for p in out.rglob("*"))
    report = bench.build(bench.source, out)
    after = sorted((p.relative_to(out).as_posix(), p.stat().st_size) for p in out.rglob("*"))
    caught = isinstance(report, LadsError) and "run.json" in str(report)
    return Result(kind, "error", caught, caught and before == after, str(report)[:300])


def call_lads(args: list[str], cwd: Path, **kw: Any) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "lads.cli", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        **kw,
    )


def build_args(bench: Bench, out: Path, *extra: str) -> list[str]:
    return [
        "build",
        "--source",
        "semantickitti",
        "--variant",
        bench.variant,
        "--in",
        str(bench.source),
        "--out",
        str(out),
        "--no-figures",
        *extra,
    ]
