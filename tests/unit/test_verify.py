"""`lads verify` on fake trees written to the letter of docs/output_tree.md.

`build_fake_tree` (tests/fake_trees.py) writes a 3-item SemanticKITTI-like source tree and a
variant tree of random bytes with its manifest.jsonl, run.json, pipeline.yaml, provenance.zarr
and SHA256SUMS; each test then breaks one thing (or several) and checks what verify reports.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path
from urllib.parse import quote

import pytest

from lads.verify import VerifyReport, parse_sums, verify_tree
from tests.fake_trees import (
    COPIED,
    build_fake_tree,
    read_manifest,
    read_run,
    sha256,
    write_manifest,
    write_run,
    write_sums,
)


def ids(out: Path) -> list[str]:
    return [r["item_id"] for r in read_manifest(out)]


def kinds(report: VerifyReport) -> set[str]:
    return {p.kind for p in report.problems}


def at(report: VerifyReport, path: str) -> set[str]:
    return {p.kind for p in report.problems if p.path == path}


@pytest.fixture
def tree(tmp_path: Path) -> tuple[Path, Path]:
    return build_fake_tree(tmp_path)


SCAN1 = "sequences/00/velodyne/000001.bin"
LABEL1 = "sequences/00/labels/000001.label"


# -- the good tree ------------------------------------------------------------------------
def test_good_tree_verifies(tree):
    src, out = tree
    report = verify_tree(out, src, source_items=ids(out))
    assert report.ok, report.summary_text()
    n_sums = len((out / "SHA256SUMS").read_text().splitlines())
    assert report.files_checked == n_sums
    assert report.items == 3
    assert report.source_files_checked == 3 * 2 + 3
    assert report.bytes_hashed > 0
    payload = json.loads(report.to_json())
    assert payload["ok"] is True and payload["problems"] == []
    assert "OK" in report.summary_text()


def test_good_aligned_tree_verifies(tmp_path):
    src, out = build_fake_tree(tmp_path, mode="aligned")
    assert verify_tree(out, src, source_items=ids(out)).ok


def test_tree_alone_without_source(tree):
    _, out = tree
    report = verify_tree(out, None)
    assert report.ok, report.summary_text()
    assert report.source_files_checked == 0


@pytest.mark.skipif(shutil.which("sha256sum") is None, reason="no sha256sum binary")
def test_coreutils_sha256sum_accepts_good_tree(tree):
    _, out = tree
    done = subprocess.run(
        ["sha256sum", "--strict", "-c", "SHA256SUMS"], cwd=out, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout + done.stderr


def test_source_items_listed_by_the_reader(tree):
    pytest.importorskip("lads.readers")
    src, out = tree
    report = verify_tree(out, src)  # source_items=None: the semantickitti reader lists them
    assert report.ok, report.summary_text()
    assert not any("not checked" in n for n in report.notes)
    (src / "sequences/00/velodyne/000003.bin").write_bytes(b"\0" * 16 * 50)
    (src / "sequences/00/labels/000003.label").write_bytes(b"\0" * 4 * 50)
    report = verify_tree(out, src)
    assert at(report, "sequences/00/velodyne/000003.bin") == {"missing_source_item"}


def test_source_listing_skipped_with_note_when_readers_unavailable(tree, monkeypatch):
    src, out = tree
    monkeypatch.setitem(sys.modules, "lads.readers", None)  # import raises ImportError
    report = verify_tree(out, src)
    assert report.ok
    assert any("not checked" in n and "get_reader" in n for n in report.notes)


# -- single faults ------------------------------------------------------------------------
def test_missing_file(tree):
    src, out = tree
    (out / LABEL1).unlink()
    report = verify_tree(out, src, source_items=ids(out))
    assert at(report, LABEL1) == {"missing_output"}
    assert kinds(report) == {"missing_output"}


def test_extra_and_temp_files(tree):
    src, out = tree
    (out / "sequences/00/velodyne/999999.bin").write_bytes(b"x" * 16)
    (out / "sequences/00/labels/000000.label.tmp").write_bytes(b"x")
    report = verify_tree(out, src, source_items=ids(out))
    assert at(report, "sequences/00/velodyne/999999.bin") == {"extra_file"}
    assert at(report, "sequences/00/labels/000000.label.tmp") == {"stray_temp_file"}
    assert kinds(report) == {"extra_file", "stray_temp_file"}


def test_unfinished_build_journal_is_one_problem(tree):
    from lads.verify import BUILD_STATE_DIR

    try:
        from lads.built_tree import STATE_DIR
    except ImportError:
        STATE_DIR = BUILD_STATE_DIR
    assert STATE_DIR == BUILD_STATE_DIR
    src, out = tree
    for i in range(3):
        (out / BUILD_STATE_DIR / f"{i}.json").parent.mkdir(exist_ok=True)
        (out / BUILD_STATE_DIR / f"{i}.json").write_text("{}")
    report = verify_tree(out, src)
    assert [(p.path, p.kind) for p in report.problems] == [(BUILD_STATE_DIR, "stray_temp_file")]


def test_truncated_file_size_and_checksum(tree):
    src, out = tree
    path = out / SCAN1
    path.write_bytes(path.read_bytes()[:-16])
    report = verify_tree(out, src, source_items=ids(out))
    assert {"size_mismatch", "checksum_mismatch"} <= at(report, SCAN1)
    messages = " ".join(p.message for p in report.problems if p.kind == "size_mismatch")
    assert "rebuild" in messages


def test_single_flipped_byte_is_checksum_only(tree):
    src, out = tree
    path = out / LABEL1
    data = bytearray(path.read_bytes())
    data[7] ^= 0x01
    path.write_bytes(bytes(data))
    report = verify_tree(out, src, source_items=ids(out))
    assert kinds(report) == {"checksum_mismatch"}
    assert [p.path for p in report.problems] == [LABEL1]


def test_label_record_count_differs_from_scan(tree):
    src, out = tree
    rows = read_manifest(out)
    label = rows[1]["outputs"][1]
    data = (out / label["path"]).read_bytes()[:-4]  # one label fewer than points
    (out / label["path"]).write_bytes(data)
    label |= {
        "bytes": len(data),
        "records": len(data) // 4,
        "sha256": hashlib.sha256(data).hexdigest(),
    }
    write_manifest(out, rows)
    write_sums(out)
    report = verify_tree(out, src, source_items=ids(out))
    assert at(report, LABEL1) == {"label_count_mismatch"}
    assert "checksum_mismatch" not in kinds(report)


def test_record_bytes_times_records_must_equal_bytes(tree):
    src, out = tree
    rows = read_manifest(out)
    rows[0]["outputs"][0]["record_bytes"] = 20
    write_manifest(out, rows)
    write_sums(out)
    report = verify_tree(out, src)
    assert "record_count_mismatch" in at(report, "sequences/00/velodyne/000000.bin")


def test_copied_file_differs_from_source(tree):
    src, out = tree
    rel = COPIED[0]
    (out / rel).write_text("P0: tampered\n")
    run = read_run(out)
    for entry in run["copied_files"]:
        if entry["path"] == rel:
            entry |= {"bytes": (out / rel).stat().st_size, "sha256": sha256(out / rel)}
    write_run(out, run)
    write_sums(out)
    assert verify_tree(out, None).ok  # consistent on its own ...
    report = verify_tree(out, src, source_items=ids(out))  # ... but not a copy of the source
    assert at(report, rel) == {"copied_file_differs"}
    assert kinds(report) == {"copied_file_differs"}


def test_changed_source_file(tree):
    src, out = tree
    path = src / "sequences/00/velodyne/000002.bin"
    data = bytearray(path.read_bytes())
    data[0] ^= 0xFF
    path.write_bytes(bytes(data))
    report = verify_tree(out, src, source_items=ids(out))
    assert at(report, "sequences/00/velodyne/000002.bin") == {"source_changed"}
    assert kinds(report) == {"source_changed"}


def test_manifest_rows_out_of_order(tree):
    src, out = tree
    rows = read_manifest(out)
    rows[0], rows[1] = rows[1], rows[0]
    write_manifest(out, rows)
    write_sums(out)
    report = verify_tree(out, src, source_items=ids(out))
    assert at(report, "manifest.jsonl") == {"manifest_inconsistent"}
    assert any("sorted by item_id" in p.message for p in report.problems)


def test_duplicate_manifest_row(tree):
    src, out = tree
    rows = read_manifest(out)
    write_manifest(out, [rows[0], *rows])
    run = read_run(out)
    run["items"] = 4
    write_run(out, run)
    write_sums(out)
    report = verify_tree(out, src)
    assert any("listed twice" in p.message for p in report.problems)


def test_failed_item(tree):
    src, out = tree
    rows = read_manifest(out)
    failed = rows[2]
    for o in failed["outputs"]:
        (out / o["path"]).unlink()
    shutil.rmtree(out / "provenance.zarr" / quote(failed["item_id"].partition(":")[2], safe=""))
    rows[2] = {
        "item_id": failed["item_id"],
        "status": "failed",
        "error": "CorruptItemError: x",
        "source": [],
        "outputs": [],
    }
    write_manifest(out, rows)
    run = read_run(out)
    run["failed"] = 1
    write_run(out, run)
    write_sums(out)
    report = verify_tree(out, src, source_items=[r["item_id"] for r in rows])
    assert kinds(report) == {"failed_item"}
    (problem,) = report.problems
    assert problem.path == "sequences/00/velodyne/000002.bin"
    assert "CorruptItemError" in problem.message and "re-run" in problem.message


def test_points_arithmetic(tree):
    src, out = tree
    rows = read_manifest(out)
    rows[0]["points"]["lost"] += 1  # output + lost != source
    write_manifest(out, rows)
    write_sums(out)
    report = verify_tree(out, src)
    assert kinds(report) == {"manifest_inconsistent"}
    assert any("output + lost == source" in p.message for p in report.problems)


def test_scan_records_must_be_the_ones_run_json_names(tree):
    """A tree records its scans' columns (a transfer may write the target's record): the
    manifest's record bytes must be four per column, and the source's scans the source's."""
    src, out = tree
    run = read_run(out)
    assert run.get("point_columns", ["x", "y", "z", "intensity"]) == ["x", "y", "z", "intensity"]
    write_run(out, {**run, "point_columns": ["x", "y", "z", "intensity", "ring"]})
    write_sums(out)
    report = verify_tree(out, src)
    assert kinds(report) == {"manifest_inconsistent"}
    assert any("run.json point_columns" in p.message for p in report.problems)
    write_run(out, {**run, "source_point_columns": ["x", "y", "z", "intensity", "ring"]})
    write_sums(out)
    report = verify_tree(out, src)
    assert any("source x source record_bytes" in p.message for p in report.problems)


def test_aligned_label_must_equal_source(tmp_path):
    src, out = build_fake_tree(tmp_path, mode="aligned")
    rows = read_manifest(out)
    label = rows[0]["outputs"][1]
    data = bytearray((out / label["path"]).read_bytes())
    data[0] ^= 1
    (out / label["path"]).write_bytes(bytes(data))
    label["sha256"] = hashlib.sha256(bytes(data)).hexdigest()
    write_manifest(out, rows)
    write_sums(out)
    report = verify_tree(out, src)
    assert at(report, label["path"]) == {"aligned_label_differs"}


def test_layout_mismatch(tree):
    src, out = tree
    rows = read_manifest(out)
    old = rows[0]["outputs"][1]["path"]
    new = "labels_elsewhere/000000.label"
    (out / new).parent.mkdir()
    (out / old).rename(out / new)
    rows[0]["outputs"][1]["path"] = new
    write_manifest(out, rows)
    write_sums(out)
    report = verify_tree(out, src)
    assert at(report, new) == {"layout_mismatch"}


def test_source_item_correspondence(tree):
    src, out = tree
    given = ids(out)[1:] + ["semantickitti:sequences/00/velodyne/000003.bin"]
    report = verify_tree(out, src, source_items=given)
    assert at(report, "sequences/00/velodyne/000003.bin") == {"missing_source_item"}
    assert at(report, "sequences/00/velodyne/000000.bin") == {"extra_output_item"}


def test_provenance_attributes_checked(tree):
    import zarr

    src, out = tree
    group = zarr.open_group(out / "provenance.zarr" / quote(SCAN1, safe=""), mode="r+")
    group.attrs["n_output"] = 1
    write_sums(out)
    report = verify_tree(out, src)
    assert kinds(report) == {"provenance_mismatch"}


def test_sums_binary_marker_and_malformed_lines(tree):
    src, out = tree
    lines = (out / "SHA256SUMS").read_text().splitlines()
    digest, rel = lines[0].split("  ", 1)
    lines[0] = f"{digest} *{rel}"  # binary-mode marker: accepted
    (out / "SHA256SUMS").write_text("\n".join(lines) + "\n")
    assert verify_tree(out, src).ok
    (out / "SHA256SUMS").write_text("\n".join(lines) + "\nnot a checksum line\n")
    report = verify_tree(out, src)
    assert at(report, "SHA256SUMS") == {"sums_invalid"}


def test_parse_sums_rejects_escapes_from_the_tree():
    good = "a" * 64
    sums, bad = parse_sums(f"{good}  b\n{good}  a\n{good}  ../etc/passwd\n{good}  b\n")
    assert sums == {"b": good, "a": good}
    reasons = " ".join(why for _, why in bad)
    assert "sort order" in reasons and "relative path" in reasons and "twice" in reasons


def test_card_invalid(tree):
    src, out = tree
    (out / "README.md").write_text("---\nlicense: not-a-licence\n---\n# card\n")
    write_sums(out)
    report = verify_tree(out, src)
    assert at(report, "README.md") == {"card_invalid"}


def test_missing_tree(tmp_path):
    report = verify_tree(tmp_path / "nowhere", None)
    assert kinds(report) == {"missing_output"}


def test_inventory_incomplete(tree):
    src, out = tree
    report = verify_tree(out, src, inventory="semantickitti-00-10")
    assert "incomplete_release" in kinds(report)
    text = " ".join(p.message for p in report.problems)
    assert "01, 02" in text and "expected 4541" in text
    other = verify_tree(out, src, inventory="voxelscape")  # another dataset's inventory
    assert kinds(other) == {"inventory_other_dataset"}
    assert "built from source 'semantickitti'" in other.problems[0].message


# -- several faults at once, and regeneration ---------------------------------------------
def test_every_problem_is_reported(tree):
    src, out = tree
    (out / LABEL1).unlink()  # missing
    scan0 = out / "sequences/00/velodyne/000000.bin"
    scan0.write_bytes(scan0.read_bytes()[:-3])  # truncated mid-record
    (out / "stray.bin").write_bytes(b"?")  # extra
    (out / COPIED[1]).write_text("changed\n")  # copied file altered (checksum)
    (src / "sequences/00/labels/000002.label").write_bytes(b"\0" * 8)  # source changed
    report = verify_tree(out, src, source_items=ids(out))
    assert {
        "missing_output",
        "size_mismatch",
        "checksum_mismatch",
        "record_count_mismatch",
        "extra_file",
        "copied_file_differs",
        "source_changed",
    } <= kinds(report)
    assert at(report, LABEL1) == {"missing_output"}
    assert at(report, "stray.bin") == {"extra_file"}
    assert at(report, "sequences/00/labels/000002.label") == {"source_changed"}
    text = report.summary_text()
    assert "FAILED" in text and "missing_output" in text


@pytest.fixture
def fake_regenerate(monkeypatch, tree):
    """Monkeypatched lads.worker.regenerate_outputs: the manifest's hashes, one of them wrong."""
    calls = []
    _, out = tree
    wrong = "semantickitti:" + SCAN1

    def regenerate_outputs(out_root, source_root, item_ids):
        calls.append(list(item_ids))
        rows = {r["item_id"]: r for r in read_manifest(Path(out_root))}
        got = {i: {o["path"]: o["sha256"] for o in rows[i]["outputs"]} for i in item_ids}
        if wrong in got:
            got[wrong][SCAN1] = "0" * 64
        return got

    monkeypatch.setattr("lads.worker.regenerate_outputs", regenerate_outputs)
    return calls


def test_regenerate_detects_a_wrong_hash(tree, fake_regenerate):
    src, out = tree
    report = verify_tree(out, src, regenerate=3, seed=0, source_items=ids(out))
    assert fake_regenerate == [ids(out)]
    assert report.regenerated == 3
    assert kinds(report) == {"regenerated_differs"}
    (problem,) = report.problems
    assert problem.path == SCAN1 and "0" * 64 in problem.message


def test_regenerate_picks_k_ok_items_reproducibly(tree, fake_regenerate):
    src, out = tree
    first = verify_tree(out, src, regenerate=2, seed=5)
    second = verify_tree(out, src, regenerate=2, seed=5)
    assert fake_regenerate[0] == fake_regenerate[1] and len(fake_regenerate[0]) == 2
    assert first.regenerated == second.regenerated == 2


def test_regenerate_needs_a_source(tree, fake_regenerate):
    _, out = tree
    report = verify_tree(out, None, regenerate=1)
    assert kinds(report) == {"regenerate_no_source"}
    assert "--against" in report.problems[0].message


def test_regenerate_of_a_tree_whose_every_item_failed_says_so(tree, fake_regenerate):
    src, out = tree
    rows = [
        {"item_id": r["item_id"], "status": "failed", "error": "CorruptItemError: x",
         "source": [], "outputs": []}
        for r in read_manifest(out)
    ]  # fmt: skip
    write_manifest(out, rows)
    report = verify_tree(out, src, regenerate=2, source_items=[r["item_id"] for r in rows])
    (problem,) = [p for p in report.problems if p.kind.startswith("regenerate")]
    assert problem.kind == "regenerate_nothing_built"
    assert "no built item" in problem.message and "re-run the build" in problem.message
    assert fake_regenerate == []


def test_a_deleted_or_edited_card_is_remade_with_lads_card(tree):
    src, out = tree
    (out / "README.md").unlink()
    report = verify_tree(out, src, source_items=ids(out))
    assert at(report, "README.md") == {"card_invalid"}
    assert "lads card" in report.problems[0].message
