"""The demo and the `lads weather` command do real work on data lads makes itself."""

import json

import numpy as np
from click.testing import CliRunner

from lads.cli import EXIT_LADS_ERROR, main
from lads.demo import run_demo
from lads.sensors.profile import load_profile
from lads.synthetic import synthetic_scan


def test_demo_writes_a_figure_and_a_summary_with_weather_effects(tmp_path):
    summary = run_demo(tmp_path)
    assert (tmp_path / "weather_demo.png").stat().st_size > 10_000
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    n = summary["input_points"]
    assert n > 50_000
    for info in summary["weather"].values():
        assert sum(info["counts"].values()) == n
        assert info["counts"]["particle"] > 0
        assert info["extinction_per_m"] > 0


def _write_scan(tmp_path, sensor="hdl64e"):
    scan = synthetic_scan(load_profile(sensor), seed=3)
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
        ["weather", str(path), str(out), "--sensor", "hdl64e", "--snow", "10",
         "--labels", str(tmp_path / "scan.label")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    written = np.fromfile(out, dtype=np.float32).reshape(-1, 4)
    written_labels = np.fromfile(out.with_suffix(".label"), dtype=np.uint32)
    assert written_labels.size == written.shape[0] <= points.shape[0]
    assert set(np.unique(written_labels)) <= set(np.unique(labels))
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
    assert "not a multiple of 4 columns" in result.output


def test_profiles_command_lists_every_shipped_sensor():
    result = CliRunner().invoke(main, ["profiles"])
    assert result.exit_code == 0
    for name in ("hdl64e", "hdl32e", "wads64"):
        assert name in result.output
