"""The robustness suite on disk: every `C-<corruption>-<severity>` variant builds, verifies
and regenerates byte for byte; `lads suite` builds a chosen set with suite.json; sources
without labels get no wet ground."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lads.cli import main
from lads.config import pipeline_for, variants_for
from lads.corruptions import CORRUPTIONS
from lads.errors import ConfigError
from lads.physics.severity import SEVERITIES
from lads.runner import run_build
from lads.stage_params import FAULT_STAGES
from lads.suite import suite_variants
from lads.synth.writer import write_synthetic_dataset
from lads.verify import verify_tree


@pytest.fixture(scope="module")
def street(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("street") / "src"
    write_synthetic_dataset(root, frames=2)
    return root


def _manifest(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def test_every_corruption_and_severity_is_a_variant_of_a_labelled_source():
    names = {
        f"C-{c}-{s}" for c, spec in CORRUPTIONS.items() if spec.has_presets for s in SEVERITIES
    }
    assert names <= set(variants_for("semantickitti"))
    radiate = {v for v in variants_for("radiate") if v.startswith("C-")}
    unlabelled = {v for v in names if not CORRUPTIONS[v[2:].rpartition("-")[0]].needs_labels}
    assert radiate == unlabelled and "C-wet_ground-heavy" not in radiate
    pipeline = pipeline_for("nuscenes", "C-beam_missing-moderate")
    assert pipeline.stages[0].stage == "beam_missing"
    assert pipeline.stages[0].params == {"severity": "moderate", "lost_channel_share": 0.5}
    with pytest.raises(ConfigError, match="C-hail-heavy"):
        pipeline_for("semantickitti", "C-hail-heavy")


@pytest.mark.parametrize("name", [n for n, spec in CORRUPTIONS.items() if spec.has_presets])
def test_heavy_corruption_builds_verifies_and_regenerates(street, tmp_path, name):
    out = tmp_path / "out"
    pipeline = pipeline_for("semantickitti", f"C-{name}-heavy")
    report = run_build("semantickitti", street, out, pipeline, jobs=1, progress=False)
    assert report.complete, report.failed
    check = verify_tree(out, street, regenerate=2, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]
    points = [row["points"] for row in _manifest(out) if "points" in row]
    assert points
    if name == "motion_distortion":
        assert all(p["displaced"] > 0.99 * p["source"] and p["lost"] == 0 for p in points)
    elif name == "beam_missing":
        assert all(0.1 < p["output"] / p["source"] < 0.4 for p in points)
    elif name == "crosstalk":
        assert all(p["particle"] == round(0.01 * p["source"]) for p in points)
    else:
        assert all(p["output"] != p["source"] or p["attenuated"] > 0 for p in points)
    card = (out / "README.md").read_text()
    word = "sensor-fault" if CORRUPTIONS[name].stage in FAULT_STAGES else "weather"
    assert f"a {word} variant" in card


def test_suite_command_builds_the_chosen_set_with_its_summary(street, tmp_path):
    out = tmp_path / "suite"
    args = [
        "suite",
        "--source",
        "semantickitti",
        "--in",
        str(street),
        "--out",
        str(out),
        "--corruptions",
        "beam_missing,motion_blur",
        "--severities",
        "light",
        "--no-figures",
    ]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "suite.json").read_text())
    assert [v["variant"] for v in summary["variants"]] == [
        "C-beam_missing-light",
        "C-motion_distortion-light",
    ]
    assert summary["complete"] and summary["variants"][1]["speed_m_s"] == 5.0
    front = (out / "README.md").read_text()
    assert "[C-motion_distortion-light](C-motion_distortion-light/README.md)" in front
    for variant in ("C-beam_missing-light", "C-motion_distortion-light"):
        assert verify_tree(out / variant, street).ok
    scan = np.fromfile(out / "C-beam_missing-light" / "sequences/00/velodyne/000000.bin", "<f4")
    assert scan.size % 4 == 0


def test_suite_refuses_unknown_or_impossible_choices():
    with pytest.raises(ConfigError, match="need point labels"):
        suite_variants("radiate", ["wet_ground"])
    with pytest.raises(ConfigError, match="severities"):
        suite_variants("semantickitti", None, ["extreme"])
    graded = [spec for spec in CORRUPTIONS.values() if spec.has_presets]
    suite = suite_variants("semantickitti")
    # cross-sensor: 3 other profiles; the motion its poses recorded
    assert len(suite) == len(graded) * len(SEVERITIES) + 3 + 1
    assert "motion-recorded" in suite and "motion-recorded" not in suite_variants("radiate")
    assert "motion-recorded" not in suite_variants("semantickitti", None, ["heavy"])
    assert suite_variants("semantickitti", ["cross_sensor"]) == [
        "sensor-hdl32e",
        "sensor-voxelscape64",
        "sensor-wads64",
    ]
    with pytest.raises(ConfigError, match="cannot take"):
        suite_variants("radiate", ["cross_sensor"])


def test_motion_recorded_takes_each_frames_speed_from_the_poses(street, tmp_path):
    from lads.synth.scene import EGO_SPEED_M_S

    out = tmp_path / "motion"
    pipeline = pipeline_for("semantickitti", "motion-recorded")
    report = run_build("semantickitti", street, out, pipeline, jobs=1, progress=False)
    assert report.complete, report.failed
    rows = [r for r in _manifest(out) if "points" in r]
    assert len(rows) == 2
    for row in rows:
        # the street is driven at a constant speed with a slight sway: the poses say so
        assert abs(row["conditions"]["speed_m_s"] - EGO_SPEED_M_S) < 0.05
        assert abs(row["conditions"]["yaw_rate_deg_s"]) < 10.0
        assert row["points"]["displaced"] > 0.9 * row["points"]["source"]
        # the motion came from the poses: a changed pose file is a changed source
        assert {"sequences/00/poses.txt", "sequences/00/calib.txt"} <= {
            s["path"] for s in row["source"]
        }
    check = verify_tree(out, street, regenerate=2, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]
    # the seam behind the vehicle opens by about v T
    src = np.fromfile(street / "sequences/00/velodyne/000001.bin", "<f4").reshape(-1, 4)
    dst = np.fromfile(out / "sequences/00/velodyne/000001.bin", "<f4").reshape(-1, 4)
    behind = (src[:, 0] < -3.0) & (np.abs(src[:, 1]) < 1.0)
    shift = np.abs(dst[behind, 0] - src[behind, 0])
    assert 0.3 < np.median(shift) < 0.6  # up to v T / 2 = 0.5 m at the seam


def test_motion_recorded_is_refused_for_a_source_without_poses(tmp_path):
    with pytest.raises(ConfigError, match="motion-recorded"):
        pipeline_for("radiate", "motion-recorded")


def test_motion_recorded_reads_nuscenes_ego_poses_and_timestamps(tmp_path):
    from lads.synth.scene import EGO_SPEED_M_S
    from lads.synth.writer import NUSC_KEYFRAME_US

    src = tmp_path / "src"
    write_synthetic_dataset(src, frames=3, layout="nuscenes", azimuth_bins=256)
    out = tmp_path / "out"
    pipeline = pipeline_for("nuscenes", "motion-recorded")
    report = run_build("nuscenes", src, out, pipeline, jobs=1, progress=False, figures=False)
    assert report.complete, report.failed
    # each 10 Hz step of the street (1 m) is a keyframe stamped NUSC_KEYFRAME_US later, so the
    # tables' poses and timestamps say 1 m per 0.5 s
    expected = EGO_SPEED_M_S * 0.1 / (NUSC_KEYFRAME_US * 1e-6)
    rows = [row for row in _manifest(out) if "points" in row]
    speeds = [row["conditions"]["speed_m_s"] for row in rows]
    assert len(speeds) == 3 and all(abs(s - expected) < 0.02 for s in speeds)
    tables = {f"v1.0-mini/{t}.json" for t in ("ego_pose", "calibrated_sensor", "sample_data")}
    assert all(tables <= {s["path"] for s in row["source"]} for row in rows)


def test_suite_lists_the_recorded_motion_beside_the_preset_speeds(street, tmp_path):
    from lads.suite import build_suite

    variants = suite_variants("semantickitti", ["motion_blur"])
    assert variants[-1] == "motion-recorded" and len(variants) == len(SEVERITIES) + 1
    suite = build_suite(
        "semantickitti", street, tmp_path / "suite", variants[-1:], progress=False, figures=False
    )
    assert suite.complete
    row = json.loads((tmp_path / "suite" / "suite.json").read_text())["variants"][0]
    assert row["severity"] == "recorded" and "poses" in row["speed_m_s"]
    front = (tmp_path / "suite" / "README.md").read_text()
    assert "| motion_distortion | recorded | speed_m_s per frame, from the poses" in front


def test_a_limited_suite_says_it_is_a_trial_subset(street, tmp_path):
    from lads.suite import build_suite

    suite = build_suite(
        "semantickitti",
        street,
        tmp_path / "suite",
        ["C-beam_missing-light"],
        progress=False,
        figures=False,
        limit=1,
    )
    assert suite.complete
    summary = json.loads((tmp_path / "suite" / "suite.json").read_text())
    assert summary["trial_subset"] is True
    assert summary["variants"][0]["items"] == 1 and summary["variants"][0]["source_items"] == 2
    assert "A trial subset (`--limit`)" in (tmp_path / "suite" / "README.md").read_text()
