"""`lads weather` runs the build's own weather stage on a lone scan file: particle labels,
severity presets, return modes, physics settings and detection rules as in a build."""

import numpy as np
import pytest
from click.testing import CliRunner

from lads.cli import EXIT_LADS_ERROR, main
from lads.cli_options import RETURN_MODES, WEATHER_SETTINGS
from lads.physics import weather as wx
from lads.physics.result import Outcome
from lads.physics.severity import PRESETS
from lads.sensors.profile import load_profile
from lads.stage_params import RETURN_MODES as STAGE_RETURN_MODES
from lads.stages.weather import WeatherStage
from lads.synth import synth_frame

PARTICLE = 7  # a class the synthetic street's labels do not use


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """A synthetic HDL-64E scan file, its uint32 labels and a uint8 copy of them."""
    folder = tmp_path_factory.mktemp("scan")
    frame = synth_frame(load_profile("hdl64e"), frames=1, seed=3, index=0)
    points = np.column_stack([frame.xyz, frame.intensity]).astype(np.float32)
    points.tofile(folder / "scan.bin")
    labels = frame.labels.astype(np.uint32)
    assert PARTICLE not in labels
    labels.tofile(folder / "scan.label")
    labels.astype(np.uint8).tofile(folder / "scan_lidarseg.bin")
    return folder, points, labels


def weather(folder, *args):
    out = folder / "out.bin"
    result = CliRunner().invoke(
        main, ["weather", str(folder / "scan.bin"), str(out), "--sensor", "hdl64e", *args]
    )
    return result, out


def test_the_shared_option_choices_are_the_stages_own():
    assert RETURN_MODES == STAGE_RETURN_MODES
    assert set(WEATHER_SETTINGS) == set(wx.SETTINGS)


@pytest.mark.parametrize("mode", ["strongest", "dual"])
def test_particles_get_the_particle_label_and_other_points_their_beams(scan, mode):
    folder, points, labels = scan
    args = ["--snow", "10", "--mode", mode, "--seed", "4"]
    result, out = weather(folder, *args, "--labels", str(folder / "scan.label"),
                          "--particle-label", str(PARTICLE))  # fmt: skip
    assert result.exit_code == 0, result.output
    expected = WeatherStage("snow", rate_mm_h=10.0, mode=mode).simulate(
        points[:, :3], points[:, 3], "hdl64e", np.random.default_rng(4)
    )
    written = np.fromfile(out, dtype=np.float32).reshape(-1, 4)
    np.testing.assert_array_equal(written[:, :3], expected.xyz)
    np.testing.assert_array_equal(written[:, 3], expected.intensity)
    carried = np.fromfile(out.with_suffix(".label"), dtype=np.uint32)
    particle = expected.outcome == Outcome.PARTICLE
    assert particle.sum() > 10
    assert np.all(carried[particle] == PARTICLE)
    np.testing.assert_array_equal(carried[~particle], labels[expected.source_index[~particle]])


def test_labels_without_a_particle_label_are_refused_before_any_output(scan):
    folder, _, _ = scan
    (folder / "out.bin").unlink(missing_ok=True)
    result, out = weather(folder, "--rain", "5", "--labels", str(folder / "scan.label"))
    assert result.exit_code == 2
    assert "--particle-label" in result.output and "semantickitti 1" in result.output
    assert not out.exists()


def test_uint8_lidarseg_labels_are_read_by_their_size(scan):
    folder, _, labels = scan
    lidarseg = str(folder / "scan_lidarseg.bin")
    result, out = weather(folder, "--snow", "10", "--labels", lidarseg, "--particle-label", "0",
                          "--labels-out", str(folder / "o_lidarseg.bin"))  # fmt: skip
    assert result.exit_code == 0, result.output
    carried = np.fromfile(folder / "o_lidarseg.bin", dtype=np.uint8)
    assert carried.size == np.fromfile(out, dtype=np.float32).size // 4
    assert set(np.unique(carried)) <= set(np.unique(labels.astype(np.uint8))) | {0}
    too_big, _ = weather(folder, "--snow", "10", "--labels", lidarseg, "--particle-label", "300")
    assert too_big.exit_code == EXIT_LADS_ERROR and "does not fit the uint8" in too_big.output
    (folder / "short.label").write_bytes(b"\0" * 12)
    short, _ = weather(folder, "--snow", "1", "--labels", str(folder / "short.label"),
                       "--particle-label", "0")  # fmt: skip
    assert short.exit_code == EXIT_LADS_ERROR and "uint32 labels" in short.output


@pytest.mark.parametrize("name", ["rain", "snow", "fog"])
def test_a_severity_name_is_its_presets_value(scan, name):
    folder, _, _ = scan
    key, values = PRESETS[name]
    by_name, out = weather(folder, f"--{name}", "heavy")
    assert by_name.exit_code == 0, by_name.output
    assert "heavy preset" in by_name.output
    named = out.read_bytes()
    by_value, out = weather(folder, f"--{name}", str(values["heavy"]))
    assert by_value.exit_code == 0 and out.read_bytes() == named


def test_settings_and_detection_reach_the_stage_and_are_checked_as_in_a_build(scan):
    folder, points, _ = scan
    lisa, out = weather(folder, "--rain", "0", "--weather-settings", "lisa")
    assert lisa.exit_code == 0, lisa.output
    expected = WeatherStage("rain", rate_mm_h=0.0, settings="lisa").simulate(
        points[:, :3], points[:, 3], "hdl64e", np.random.default_rng(0)
    )
    assert expected.lost_index.size > 0  # LISA's fixed threshold drops weak clear-air returns
    assert out.read_bytes() == np.column_stack([expected.xyz, expected.intensity]).tobytes()
    fixed, out = weather(folder, "--rain", "0", "--detection", str(0.9 / 200**2))
    assert (
        fixed.exit_code == 0
        and out.read_bytes() == np.column_stack([expected.xyz, expected.intensity]).tobytes()
    )
    no_fog, _ = weather(folder, "--fog", "50", "--weather-settings", "lisa")
    assert no_fog.exit_code == EXIT_LADS_ERROR and "no fog model" in no_fog.output
    for bad in (["--rain", "-1"], ["--fog", "0"]):
        refused, _ = weather(folder, *bad)
        assert refused.exit_code == EXIT_LADS_ERROR, bad
    for bad in (
        ["--rain", "often"],
        ["--rain", "1", "--detection", "soft"],
        ["--snow", "1", "--fog", "9"],
    ):
        refused, _ = weather(folder, *bad)
        assert refused.exit_code == 2 and "Error" in refused.output, bad


def test_mistaken_arguments_are_refused_with_what_to_pass(scan):
    folder, _, _ = scan
    for columns in ("0", "3", "-1"):
        refused, _ = weather(folder, "--rain", "1", "--columns", columns)
        assert refused.exit_code == 2 and "--columns" in refused.output, columns
    for alone in (["--particle-label", "1"], ["--labels-out", str(folder / "x.label")]):
        refused, _ = weather(folder, "--rain", "1", *alone)
        assert refused.exit_code == 2 and "apply to --labels" in refused.output
    (folder / "scan.csv").write_text("1,2,3,4\n")
    text = CliRunner().invoke(main, ["weather", str(folder / "scan.csv"), str(folder / "o.csv"),
                                     "--sensor", "hdl32e", "--fog", "50"])  # fmt: skip
    assert text.exit_code == 2 and "--source radiate" in text.output


def test_severity_names_in_any_case_and_the_rule_used_is_reported(scan):
    folder, _, _ = scan
    upper, out = weather(folder, "--snow", "Heavy")
    assert upper.exit_code == 0, upper.output
    named = out.read_bytes()
    lower, out = weather(folder, "--snow", "heavy")
    assert out.read_bytes() == named
    assert "detection sensor (its detection limit)" in lower.output
    lisa, _ = weather(folder, "--rain", "1", "--weather-settings", "lisa")
    assert "detection LISA's fixed threshold" in lisa.output


def test_a_unit_encoded_scan_told_a_byte_sensor_is_refused(scan):
    folder, _, _ = scan
    out = folder / "byte.bin"
    args = ["weather", str(folder / "scan.bin"), str(out), "--sensor", "hdl32e"]
    result = CliRunner().invoke(main, [*args, "--columns", "4", "--rain", "5"])
    assert result.exit_code == EXIT_LADS_ERROR and "look unit-encoded" in result.output
    assert not out.exists()
