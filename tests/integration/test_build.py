"""`lads build` end to end on synthetic SemanticKITTI-layout trees that lads writes itself.

Specification: one output item per source item at the same relative path and in the same
format; labels rewritten (physical) or byte-identical (aligned); provenance traces every
point; the bytes do not depend on job count or backend; a killed build resumes to the same
bytes; bad items are reported and the rest is built.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lads import provenance
from lads.cli import main
from lads.config import pipeline_for
from lads.errors import BuildError
from lads.physics.result import Outcome
from lads.runner import run_build
from lads.synth import write_synthetic_dataset

FRAMES = 4
SEQ = "sequences/00"


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synth_src")
    write_synthetic_dataset(root, sensor="hdl64e", frames=FRAMES, layout="semantickitti", seed=3)
    return root


def snow(**overrides):
    # The builder's machinery on small random trees: physics intensity (the learned stage
    # has its own tests in test_build_intensity.py).
    overrides.setdefault("intensity", "physics")
    return pipeline_for("semantickitti", "snow").with_overrides(**overrides)


def tree_digest(root: Path, skip=("run_report.json",)) -> dict[str, str]:
    out = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and path.name not in skip:
            out[path.relative_to(root).as_posix()] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def built(source, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("built") / "snow"
    report = run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=0)
    assert report.complete and report.built == FRAMES
    return out


def test_output_mirrors_source_layout_and_format(source, built):
    for scan in sorted((source / SEQ / "velodyne").glob("*.bin")):
        out_scan = built / SEQ / "velodyne" / scan.name
        out_label = built / SEQ / "labels" / (scan.stem + ".label")
        n = out_scan.stat().st_size // 16
        assert out_scan.stat().st_size == n * 16 and out_label.stat().st_size == n * 4
    for name in ("calib.txt", "poses.txt", "times.txt"):
        assert (built / SEQ / name).read_bytes() == (source / SEQ / name).read_bytes()


def test_physical_mode_labels_particles_and_traces_points(source, built):
    relpath = f"{SEQ}/velodyne/000001.bin"
    src = np.fromfile(source / relpath, np.float32).reshape(-1, 4)
    src_labels = np.fromfile(source / SEQ / "labels/000001.label", np.uint32)
    out = np.fromfile(built / relpath, np.float32).reshape(-1, 4)
    labels = np.fromfile(built / SEQ / "labels/000001.label", np.uint32)
    index, outcome, attrs = provenance.read_item(built, relpath)
    assert attrs["n_source"] == src.shape[0] and index.size == out.shape[0] == labels.size
    assert np.all(np.diff(index) > 0)
    kept = outcome == Outcome.KEPT
    assert np.array_equal(out[kept], src[index[kept]])
    assert np.array_equal(
        labels[~(outcome == Outcome.PARTICLE)], src_labels[index[outcome != Outcome.PARTICLE]]
    )
    assert (outcome == Outcome.PARTICLE).sum() > 0, "10 mm/h snow should produce flake returns"
    assert np.all(labels[outcome == Outcome.PARTICLE] == 1)  # SemanticKITTI "outlier"
    # Intensity keeps the KITTI encoding: [0, 0.99] on the 0.01 grid.
    assert np.allclose(np.round(out[:, 3] * 100), out[:, 3] * 100, atol=1e-4)
    assert out[:, 3].max() <= 0.99


def test_manifest_and_checksums_describe_the_tree(source, built):
    rows = [json.loads(line) for line in (built / "manifest.jsonl").read_text().splitlines()]
    assert [r["item_id"] for r in rows] == sorted(r["item_id"] for r in rows)
    assert len(rows) == FRAMES and all(r["status"] == "ok" for r in rows)
    for row in rows:
        p = row["points"]
        assert p["kept"] + p["attenuated"] + p["particle"] == p["output"]
        assert p["output"] + p["lost"] == p["source"]
        for out in row["outputs"]:
            data = (built / out["path"]).read_bytes()
            assert len(data) == out["bytes"] == out["records"] * out["record_bytes"]
            assert hashlib.sha256(data).hexdigest() == out["sha256"]
            assert out["records"] == p["output"]
        assert row["stages"][0]["name"] == "snow" and len(row["stages"][0]["seed_entropy"]) == 5
    run = json.loads((built / "run.json").read_text())
    assert run["config_hash"] == snow(rate_mm_h=10.0).config_hash()
    assert {c["path"] for c in run["copied_files"]} == {
        f"{SEQ}/{n}" for n in ("calib.txt", "poses.txt", "times.txt")
    }
    listed = dict(
        reversed(line.split("  ", 1)) for line in (built / "SHA256SUMS").read_text().splitlines()
    )
    assert "manifest.jsonl" in listed and "run.json" in listed and "pipeline.yaml" in listed
    assert not (built / ".lads-state").exists()
    if shutil_which("sha256sum"):
        check = subprocess.run(
            ["sha256sum", "--quiet", "-c", "SHA256SUMS"], cwd=built, capture_output=True
        )
        assert check.returncode == 0, check.stdout + check.stderr


def shutil_which(name):
    import shutil

    return shutil.which(name)


def test_aligned_mode_reuses_label_files_byte_for_byte(source, tmp_path):
    out = tmp_path / "aligned"
    run_build("semantickitti", source, out, snow(rate_mm_h=10.0, points="aligned"), seed=0)
    for label in sorted((source / SEQ / "labels").glob("*.label")):
        assert (out / SEQ / "labels" / label.name).read_bytes() == label.read_bytes()
    relpath = f"{SEQ}/velodyne/000000.bin"
    pts = np.fromfile(out / relpath, np.float32).reshape(-1, 4)
    src = np.fromfile(source / relpath, np.float32).reshape(-1, 4)
    _, outcome, _ = provenance.read_item(out, relpath)
    assert pts.shape == src.shape
    lost = outcome == Outcome.LOST
    assert np.all(pts[lost] == 0)


def test_bytes_do_not_depend_on_job_count(source, built, tmp_path):
    out = tmp_path / "jobs2"
    run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=0, jobs=2)
    assert tree_digest(out) == tree_digest(built)


def test_bytes_do_not_depend_on_backend_dask(source, built, tmp_path):
    distributed = pytest.importorskip("distributed")
    out = tmp_path / "dask"
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        run_build(
            "semantickitti",
            source,
            out,
            snow(rate_mm_h=10.0),
            seed=0,
            backend="dask",
            scheduler=cluster.scheduler_address,
        )
    assert tree_digest(out) == tree_digest(built)


def test_other_seed_or_variant_changes_bytes(source, built, tmp_path):
    out = tmp_path / "seed1"
    run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=1)
    scan = f"{SEQ}/velodyne/000000.bin"
    assert (out / scan).read_bytes() != (built / scan).read_bytes()


def test_rerun_of_a_finished_build_skips_everything_and_changes_nothing(source, built):
    before = tree_digest(built)
    report = run_build("semantickitti", source, built, snow(rate_mm_h=10.0), seed=0)
    assert (report.built, report.skipped) == (0, FRAMES)
    assert tree_digest(built) == before


def test_damaged_output_is_rebuilt_on_rerun(source, built, tmp_path):
    import shutil

    out = tmp_path / "damaged"
    shutil.copytree(built, out)
    scan = out / SEQ / "velodyne/000002.bin"
    data = bytearray(scan.read_bytes())
    data[100] ^= 0xFF
    scan.write_bytes(bytes(data))
    report = run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=0)
    assert (report.built, report.skipped) == (1, FRAMES - 1)
    assert tree_digest(out) == tree_digest(built)


def test_items_an_older_stage_version_built_are_rebuilt_on_rerun(source, built, tmp_path):
    """A rerun after an upgrade that changed a stage's bytes (its version) rebuilds the items
    the older version built instead of mixing both versions in one tree."""
    import shutil

    out = tmp_path / "older"
    shutil.copytree(built, out)
    manifest = out / "manifest.jsonl"
    rows = [json.loads(line) for line in manifest.read_text().splitlines()]
    rows[1]["stages"][0]["version"] = "0"  # as an older lads recorded it
    manifest.write_text("".join(json.dumps(r) + "\n" for r in rows))
    report = run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=0)
    assert (report.built, report.skipped) == (1, FRAMES - 1)
    assert tree_digest(out) == tree_digest(built)


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ({"seed": -1}, "seed -1: expected an integer >= 0"),
        ({"jobs": 0}, "jobs 0: expected an integer >= 1"),
        ({"limit": -1}, "limit -1: expected an integer >= 1"),  # would drop the last item
        ({"batch": 0}, "batch 0: expected an integer >= 1"),
    ],
)
def test_bad_counts_are_refused_before_any_output(source, tmp_path, setting, message):
    """A negative seed or a count below 1 is a ConfigError before anything is written (the
    CLI refuses them as click ranges), not a failure of every item or joblib's ValueError."""
    from lads.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        run_build("semantickitti", source, tmp_path / "out", snow(), **setting)
    assert not (tmp_path / "out").exists()
    args = ["build", "--source", "semantickitti", "--variant", "snow", "--in", str(source)]
    flag = {"seed": "--seed", "jobs": "--jobs", "limit": "--limit", "batch": "--batch"}
    ((name, value),) = setting.items()
    result = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "o"), flag[name], str(value)])
    assert result.exit_code == 2 and "is not in the range" in result.output


def test_refuses_to_write_inside_the_source(source):
    with pytest.raises(BuildError, match="inside the source"):
        run_build("semantickitti", source, source / "out", snow(), seed=0)


def test_refuses_a_tree_built_with_other_settings(source, built):
    with pytest.raises(BuildError, match="other settings.*variant 'snow' with other param"):
        run_build("semantickitti", source, built, snow(rate_mm_h=1.0), seed=0)
    with pytest.raises(BuildError, match="variant 'snow' there, 'rain' here; seed 0 there, 1"):
        run_build("semantickitti", source, built, pipeline_for("semantickitti", "rain"), seed=1)


def test_refuses_a_foreign_nonempty_directory(source, tmp_path):
    (tmp_path / "mine.txt").write_text("precious")
    with pytest.raises(BuildError, match="not empty"):
        run_build("semantickitti", source, tmp_path, snow(), seed=0)


def test_killed_build_resumes_to_identical_bytes(source, built, tmp_path):
    """SIGKILL a CLI build mid-way, run it again: the tree equals the uninterrupted one."""
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "lads.cli",
        "build",
        "--source",
        "semantickitti",
        "--variant",
        "snow",
        "--intensity",
        "physics",
        "--rate-mm-h",
        "10",
        "--in",
        str(source),
        "--out",
        str(out),
        "--no-figures",
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    state = out / ".lads-state" / "items"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if state.is_dir() and len(list(state.glob("*.json"))) >= 1:
            break
        time.sleep(0.01)
    killed = proc.poll() is None
    if killed:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert killed, "the build finished before it could be killed; use more frames"
    assert not (out / "SHA256SUMS").exists()
    result = subprocess.run(cmd, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "skipped (already done) 0" not in result.stdout
    assert tree_digest(out) == tree_digest(built)


def _bad_tree(source: Path, root: Path) -> Path:
    import shutil

    shutil.copytree(source, root)
    seq = root / SEQ
    (seq / "velodyne/000000.bin").write_bytes((seq / "velodyne/000000.bin").read_bytes()[:-6])
    labels = seq / "labels/000001.label"
    labels.write_bytes(labels.read_bytes()[:-8])
    pts = np.fromfile(seq / "velodyne/000002.bin", np.float32).reshape(-1, 4)
    pts[5, 1] = np.nan
    pts.tofile(seq / "velodyne/000002.bin")
    return root


def test_bad_items_are_reported_and_the_rest_is_built(source, tmp_path):
    src = _bad_tree(source, tmp_path / "bad_src")
    out = tmp_path / "bad_out"
    result = CliRunner().invoke(
        main,
        [
            "build",
            "--source",
            "semantickitti",
            "--variant",
            "snow",
            "--in",
            str(src),
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 1, result.output
    assert "INCOMPLETE" in result.output
    report = json.loads((out / "run_report.json").read_text())
    failed = {f["item_id"].rsplit("/", 1)[1]: f["error"] for f in report["failed"]}
    assert set(failed) == {"000000.bin", "000001.bin", "000002.bin"}
    assert "000000.bin" in failed["000000.bin"] and "16-byte" in failed["000000.bin"]
    assert "000001.label" in failed["000001.bin"]
    assert "NaN" in failed["000002.bin"]
    assert (out / SEQ / "velodyne/000003.bin").is_file()
    rows = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    assert [r["status"] for r in rows] == ["failed", "failed", "failed", "ok"]


def test_fail_fast_stops_at_the_first_bad_item(source, tmp_path):
    src = _bad_tree(source, tmp_path / "bad_src")
    result = CliRunner().invoke(
        main,
        [
            "build",
            "--source",
            "semantickitti",
            "--variant",
            "snow",
            "--in",
            str(src),
            "--out",
            str(tmp_path / "ff"),
            "--fail-fast",
        ],
    )
    assert result.exit_code == 2
    assert "fail-fast" in result.output
    assert not (tmp_path / "ff" / SEQ / "velodyne/000003.bin").exists()


def test_cli_build_then_verify_with_regeneration(source, tmp_path):
    out = tmp_path / "cli"
    runner = CliRunner()
    result = runner.invoke(
        main,
        [
            "build",
            "--source",
            "semantickitti",
            "--variant",
            "rain",
            "--in",
            str(source),
            "--out",
            str(out),
            "--jobs",
            "2",
        ],
    )
    assert result.exit_code == 0, result.output
    result = runner.invoke(
        main, ["verify", str(out), "--against", str(source), "--regenerate", "2"]
    )
    assert result.exit_code == 0, result.output
    flipped = out / SEQ / "labels/000003.label"
    data = bytearray(flipped.read_bytes())
    data[0] ^= 1
    flipped.write_bytes(bytes(data))
    result = runner.invoke(main, ["verify", str(out), "--against", str(source)])
    assert result.exit_code == 1 and "000003.label" in result.output


def test_a_severity_preset_builds_records_both_values_and_verifies(source, tmp_path):
    import yaml

    out = tmp_path / "fog-light"
    args = [
        "build",
        "--source",
        "semantickitti",
        "--variant",
        "fog",
        "--severity",
        "light",
        "--intensity",
        "physics",
        "--in",
        str(source),
        "--out",
        str(out),
    ]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    stage = yaml.safe_load((out / "pipeline.yaml").read_text())["stages"][0]
    assert (stage["severity"], stage["visibility_m"]) == ("light", 600.0)
    assert "severity=light, visibility_m=600.0" in (out / "README.md").read_text()
    result = CliRunner().invoke(
        main, ["verify", str(out), "--against", str(source), "--regenerate", "1"]
    )
    assert result.exit_code == 0, result.output
    # A preset and a disagreeing explicit value are refused before anything is built.
    result = CliRunner().invoke(main, [*args[:-1], str(tmp_path / "x"), "--visibility-m", "80"])
    assert result.exit_code != 0 and "give one of them" in result.output
    assert not (tmp_path / "x").exists()


def test_dual_returns_build_count_and_verify_with_regeneration(source, tmp_path):
    """--mode dual: a beam's second return is written after its first, with the beam's
    label; the manifest counts it and verify (regenerating items) agrees."""
    out = tmp_path / "snow-dual"
    args = [
        "build",
        "--source",
        "semantickitti",
        "--variant",
        "snow",
        "--mode",
        "dual",
        "--rate-mm-h",
        "10",
        "--intensity",
        "physics",
        "--in",
        str(source),
        "--out",
        str(out),
    ]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    seconds = [r["points"].get("second_returns", 0) for r in rows if "points" in r]
    assert sum(seconds) > 0
    for row in rows:
        if "points" not in row:
            continue
        pts = row["points"]
        assert pts["output"] + pts["lost"] == pts["source"] + pts.get("second_returns", 0)
        source_index, outcome, _ = provenance.read_item(out, row["item_id"].partition(":")[2])
        assert np.all(np.diff(source_index) >= 0)
        # Each beam's pair holds a flake and the target (either order) or two flakes.
        second = np.flatnonzero(np.diff(source_index) == 0) + 1
        pair = np.stack([outcome[second - 1], outcome[second]], axis=1)
        assert np.all((pair == Outcome.PARTICLE).any(axis=1))
    result = CliRunner().invoke(
        main, ["verify", str(out), "--against", str(source), "--regenerate", "2"]
    )
    assert result.exit_code == 0, result.output


def test_a_limited_trial_is_a_named_subset_and_a_smaller_one_keeps_the_larger(
    source, built, tmp_path
):
    from lads.verify import verify_tree

    out = tmp_path / "trial"
    report = run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=0, limit=3)
    assert report.complete and report.subset == (3, FRAMES)
    assert f"a trial subset: 3 of the source's {FRAMES} items" in report.summary_text()
    run = json.loads((out / "run.json").read_text())
    assert run["limit"] == 3 and run["source_items"] == FRAMES
    assert (
        "a trial subset (`--limit 3`), 3 of the source's 4 scans" in (out / "README.md").read_text()
    )
    check = verify_tree(out, source)
    assert check.ok, check.problems
    assert any(
        "a trial subset (built with --limit 3): 1 of the source's 4" in n for n in check.notes
    )
    # a smaller trial after it keeps the items the larger one built (same settings, intact)
    report = run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=0, limit=1)
    assert report.complete and report.built == 0 and report.skipped == 1 and not report.foreign
    assert report.subset == (3, FRAMES)
    assert verify_tree(out, source).ok
    # the first items of a limited tree are not optional: one lost is still reported
    rows = (out / "manifest.jsonl").read_text().splitlines()
    (out / "manifest.jsonl").write_text("\n".join(rows[1:]) + "\n")
    kinds = {p.kind for p in verify_tree(out, source).problems}
    assert "missing_source_item" in kinds
    # without a limit the rest is built and the tree is the full build's
    report = run_build("semantickitti", source, out, snow(rate_mm_h=10.0), seed=0)
    assert report.complete and report.subset is None and report.built == 2  # lost row + 4th
    full, trial = tree_digest(built), tree_digest(out)
    assert {k: v for k, v in trial.items() if k != "run.json"} == {
        k: v for k, v in full.items() if k != "run.json"
    }


def test_a_backend_that_cannot_run_is_refused_before_the_output_is_made(source, tmp_path):
    import dask

    out = tmp_path / "never"
    with pytest.raises(BuildError, match="address for --backend dask"):
        run_build("semantickitti", source, out, snow(), scheduler="tcp://127.0.0.1:1")
    assert not out.exists()
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        with pytest.raises(BuildError, match="cannot reach the Dask scheduler"):
            run_build(
                "semantickitti",
                source,
                out,
                snow(),
                backend="dask",
                scheduler="tcp://127.0.0.1:1",
                progress=False,
            )


def test_a_tree_built_from_the_parent_of_dataset_verifies_against_it(source, tmp_path):
    """SemanticKITTI's reader steps into `dataset/`; verify finds the sources the same way."""
    from lads.verify import verify_tree

    parent = tmp_path / "kitti"
    (parent / "dataset").mkdir(parents=True)
    (parent / "dataset" / "sequences").symlink_to(source / "sequences")
    out = tmp_path / "out"
    report = run_build("semantickitti", parent, out, snow(rate_mm_h=10.0), seed=0, limit=2)
    assert report.complete, report.failed
    check = verify_tree(out, parent, regenerate=1, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]


def test_a_nuscenes_trial_subset_used_as_a_source_says_what_it_is(tmp_path):
    from lads.errors import ReaderError
    from lads.readers import get_reader

    src = tmp_path / "src"
    write_synthetic_dataset(src, frames=3, layout="nuscenes", azimuth_bins=256)
    out = tmp_path / "trial"
    pipeline = pipeline_for("nuscenes", "C-beam_missing-light")
    assert run_build("nuscenes", src, out, pipeline, progress=False, limit=2).complete
    with pytest.raises(ReaderError, match=r"built with --limit \(2 of 3 items\)"):
        get_reader("nuscenes", out).items()
