"""The demo and the `lads weather` command do real work on data lads makes itself."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from lads.cli import EXIT_LADS_ERROR, main
from lads.demo import run_demo, summary_text
from lads.errors import LadsError
from lads.sensors.profile import load_profile
from lads.synth import synth_frame


def test_demo_synthesises_builds_verifies_and_draws(tmp_path):
    out = tmp_path / "demo"
    summary = run_demo(out, frames=2, jobs=1)
    assert json.loads((out / "summary.json").read_text()) == summary
    assert set(summary["variants"]) == {"snow", "rain", "fog"}
    for name, info in summary["variants"].items():
        assert info["complete"] and info["verify_ok"], (name, info["verify_problems"])
        assert info["points"]["source"] == sum(summary["source_points_per_frame"])
        assert (out / name / "sequences/00/velodyne/000001.bin").is_file()
    assert summary["variants"]["snow"]["points"]["particle"] > 0
    assert summary["variants"]["fog"]["points"]["attenuated"] > 0
    for figure in ("variants_000000.png", "point_correspondence.png"):
        assert (out / "figures" / figure).stat().st_size > 10_000
    text = summary_text(summary, out)
    assert "snow" in text and "verify" in text


def test_demo_refuses_to_wipe_a_folder_it_did_not_make(tmp_path):
    (tmp_path / "thesis.tex").write_text("precious")
    with pytest.raises(LadsError, match="not a lads demo folder"):
        run_demo(tmp_path, frames=1, jobs=1)
    assert (tmp_path / "thesis.tex").is_file()


def _write_scan(tmp_path, sensor="hdl64e"):
    scan = synth_frame(load_profile(sensor), frames=1, seed=3, index=0)
    points = np.column_stack([scan.xyz, scan.intensity]).astype(np.float32)
    path = tmp_path / "scan.bin"
    points.tofile(path)
    scan.labels.tofile(tmp_path / "scan.label")
    return path, points, scan.labels


def test_weather_command_writes_scan_and_labels_that_follow_their_beams(tmp_path):
    path, points, labels = _write_scan(tmp_path)
    out = tmp_path / "out" / "scan.bin"
    result = CliRunner().invoke(
        main,
        [
            "weather",
            str(path),
            str(out),
            "--sensor",
            "hdl64e",
            "--snow",
            "10",
            "--labels",
            str(tmp_path / "scan.label"),
            "--particle-label",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    written = np.fromfile(out, dtype=np.float32).reshape(-1, 4)
    written_labels = np.fromfile(out.with_suffix(".label"), dtype=np.uint32)
    assert written_labels.size == written.shape[0] <= points.shape[0]
    # (which points carry the particle label: tests/unit/test_weather_command.py)
    assert set(np.unique(written_labels)) <= set(np.unique(labels)) | {1}
    assert "particle" in result.output


def test_weather_command_is_reproducible_by_seed(tmp_path):
    path, _, _ = _write_scan(tmp_path)
    outs = []
    for name, seed in (("a.bin", "4"), ("b.bin", "4"), ("c.bin", "5")):
        args = ["weather", str(path), str(tmp_path / name), "--sensor", "hdl64e"]
        CliRunner().invoke(main, [*args, "--rain", "50", "--seed", seed])
        outs.append((tmp_path / name).read_bytes())
    assert outs[0] == outs[1] != outs[2]


def test_bad_input_maps_to_a_clear_error_and_exit_code(tmp_path):
    path = tmp_path / "odd.bin"
    np.zeros(7, dtype=np.float32).tofile(path)
    result = CliRunner().invoke(
        main, ["weather", str(path), str(tmp_path / "o.bin"), "--sensor", "hdl64e", "--fog", "50"]
    )
    assert result.exit_code == EXIT_LADS_ERROR
    assert "not a whole number of 16-byte records" in result.output
    assert "--columns" in result.output


def test_profiles_command_lists_every_shipped_sensor():
    result = CliRunner().invoke(main, ["profiles"])
    assert result.exit_code == 0
    for name in ("hdl64e", "hdl32e", "wads64"):
        assert name in result.output


def test_an_interrupted_build_says_how_to_resume(monkeypatch, tmp_path):
    import lads.runner
    from lads.exit_codes import EXIT_INTERRUPTED

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(lads.runner, "run_build", interrupted)
    src = tmp_path / "src"
    src.mkdir()
    args = ["build", "--source", "semantickitti", "--variant", "rain", "--in", str(src),
            "--out", str(tmp_path / "out")]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == EXIT_INTERRUPTED
    assert "run the same command again to resume" in result.output
