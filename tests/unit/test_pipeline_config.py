"""Pipelines are validated data; overrides change parameters; the hash tracks every change."""

from __future__ import annotations

import pytest
import yaml

from lads.config import find_pipeline, load_pipeline, parse_pipeline, variants_for
from lads.errors import ConfigError
from lads.readers import READERS
from lads.variant_families import corruption_variants

SNOW = {
    "schema_version": 1,
    "variant": "snow",
    "stages": [{"stage": "snow", "rate_mm_h": 2.5}],
    "writer": {"points": "physical"},
}


def test_shipped_pipelines_load_and_name_their_variant():
    for variant in ("snow", "rain", "fog"):
        config = load_pipeline(find_pipeline("semantickitti", variant))
        assert config.variant == variant
        assert config.stages[0].stage == variant


def _write(path, **extra):
    path.write_text(yaml.safe_dump({**SNOW, **extra}))


def test_source_specific_pipeline_wins_over_generic(tmp_path):
    _write(tmp_path / "snow.yaml")
    _write(tmp_path / "wads-snow.yaml")
    assert find_pipeline("wads", "snow", tmp_path).name == "wads-snow.yaml"
    assert find_pipeline("semantickitti", "snow", tmp_path).name == "snow.yaml"


def test_a_source_prefix_is_the_longest_reader_name(tmp_path):
    # "nuscenes-kitti-snow" belongs to the reader nuscenes-kitti, not to nuscenes.
    _write(tmp_path / "nuscenes-kitti-snow.yaml")
    assert variants_for("nuscenes-kitti", tmp_path) == ["snow"]
    assert variants_for("nuscenes", tmp_path) == []


def test_a_pipeline_restricted_to_sources_is_no_variant_of_the_others(tmp_path):
    _write(tmp_path / "snow.yaml", sources=["wads"])
    assert variants_for("wads", tmp_path) == ["snow"]
    with pytest.raises(ConfigError, match="variants of 'semantickitti': none.*exists for: wads"):
        find_pipeline("semantickitti", "snow", tmp_path)
    pipeline = load_pipeline(tmp_path / "snow.yaml")
    pipeline.check_source("wads", "here")
    with pytest.raises(ConfigError, match="applies to sources wads, not 'radiate'"):
        pipeline.check_source("radiate", "here")


def test_unknown_variant_lists_the_valid_ones():
    with pytest.raises(ConfigError, match="variants of 'semantickitti': fog, intensity-kitti"):
        find_pipeline("semantickitti", "hail")


def test_another_sources_pipeline_file_is_not_a_variant():
    listed = "variants of 'nuscenes': fog, .*snow, wet-ground, C-<corruption>-<.*>.*\\. Pass"
    with pytest.raises(ConfigError, match=listed):
        find_pipeline("nuscenes", "voxelscape-snow")


def test_every_source_offers_every_shipped_variant():
    # The matrix users build; tests/realdata/test_matrix_real.py builds it on real frames.
    expected = ["fog", "intensity-kitti", "intensity-nuscenes", "rain", "snow"]
    # A sensor transfer needs poses and scan order: every profile but the source's own.
    to_64 = ["sensor-hdl64e", "sensor-voxelscape64", "sensor-wads64"]
    # The motion a sequence's poses recorded: the same readers.
    sensors = {
        "semantickitti": [
            "motion-recorded",
            "sensor-hdl32e",
            "sensor-voxelscape64",
            "sensor-wads64",
        ],
        "nuscenes": ["motion-recorded", *to_64],
        "nuscenes-kitti": ["motion-recorded", *to_64],
    }
    for source in READERS:
        # A wet road needs labels to find the road: every source but RADIATE has them.
        wet = [] if source == "radiate" else ["wet-ground"]
        # The robustness suite: every corruption the source can take, at every severity.
        suite = corruption_variants(source)
        assert len(suite) == (18 if source == "radiate" else 24)
        shipped = sorted(expected + sensors.get(source, []) + wet + suite)
        assert variants_for(source) == shipped, source


@pytest.mark.parametrize(
    "change, message",
    [
        ({"colour": 1}, "unknown keys"),
        ({"schema_version": 2}, "schema_version"),
        ({"stages": []}, "non-empty"),
        ({"stages": [{"stage": "hail", "rate_mm_h": 1}]}, "unknown stage"),
        ({"stages": [{"stage": "snow", "rate_mmh": 1}]}, "unknown parameters"),
        ({"stages": [{"stage": "snow"}]}, "needs"),
        ({"stages": [{"stage": "rain", "rate_mm_h": -1}]}, ">= 0"),
        ({"stages": [{"stage": "fog", "visibility_m": 0}]}, "> 0"),
        ({"stages": [{"stage": "fog", "visibility_m": 50, "mode": "first"}]}, "mode"),
        ({"writer": {"points": "sparse"}}, "writer.points"),
        ({"writer": {"points": "physical", "label": 1}}, "unknown keys"),
    ],
)
def test_invalid_pipelines_are_refused_with_the_reason(change, message):
    with pytest.raises(ConfigError, match=message):
        parse_pipeline({**SNOW, **change}, "test.yaml")


def test_overrides_change_parameters_and_hash():
    config = parse_pipeline(SNOW, "t")
    heavier = config.with_overrides(rate_mm_h=10.0, visibility_m=None)
    assert heavier.stages[0].params["rate_mm_h"] == 10.0
    assert heavier.config_hash() != config.config_hash()
    assert config.with_overrides(rate_mm_h=None).config_hash() == config.config_hash()
    aligned = config.with_overrides(points="aligned", particle_label=110)
    assert (aligned.points, aligned.particle_label) == ("aligned", 110)


def test_override_that_no_stage_accepts_is_an_error():
    with pytest.raises(ConfigError, match="--visibility-m does not apply"):
        parse_pipeline(SNOW, "t").with_overrides(visibility_m=30.0)


def test_hash_is_stable_across_dict_order():
    reordered = {
        "writer": SNOW["writer"],
        "stages": SNOW["stages"],
        "variant": "snow",
        "schema_version": 1,
    }
    assert parse_pipeline(reordered, "a").config_hash() == parse_pipeline(SNOW, "b").config_hash()


# --- severity presets -------------------------------------------------------------------

FOG = {"schema_version": 1, "variant": "fog", "stages": [{"stage": "fog", "visibility_m": 50.0}]}


@pytest.mark.parametrize(
    ("weather", "key"), [("rain", "rate_mm_h"), ("snow", "rate_mm_h"), ("fog", "visibility_m")]
)
def test_a_severity_in_the_pipeline_file_fills_in_its_physical_value(weather, key):
    from lads.physics.severity import PRESETS, SEVERITIES

    values = [PRESETS[weather][1][s] for s in SEVERITIES]
    # Heavier weather: more rain or snow, less visibility.
    assert values == sorted(values, reverse=(key == "visibility_m"))
    for severity, value in zip(SEVERITIES, values, strict=True):
        data = {
            "schema_version": 1,
            "variant": weather,
            "stages": [{"stage": weather, "severity": severity}],
        }
        stage = parse_pipeline(data, "t").stages[0]
        assert stage.params == {"severity": severity, key: value}  # both recorded


def test_a_severity_and_a_different_explicit_value_are_refused():
    data = {**SNOW, "stages": [{"stage": "snow", "severity": "light", "rate_mm_h": 2.5}]}
    with pytest.raises(ConfigError, match="give one of them"):
        parse_pipeline(data, "t.yaml")
    agreeing = {**SNOW, "stages": [{"stage": "snow", "severity": "heavy", "rate_mm_h": 2.5}]}
    assert parse_pipeline(agreeing, "t").stages[0].params["rate_mm_h"] == 2.5
    with pytest.raises(ConfigError, match="severity 'extreme'"):
        parse_pipeline({**SNOW, "stages": [{"stage": "snow", "severity": "extreme"}]}, "t")


def test_the_severity_override_replaces_the_files_strength_and_records_both():
    light = parse_pipeline(FOG, "t").with_overrides(severity="light")
    assert light.stages[0].params == {"visibility_m": 600.0, "severity": "light"}
    assert light.config_hash() != parse_pipeline(FOG, "t").config_hash()
    # An explicit value on the command line must agree with the preset.
    with pytest.raises(ConfigError, match="give one of them"):
        parse_pipeline(FOG, "t").with_overrides(severity="light", visibility_m=100.0)
    # An explicit value replaces a preset of the pipeline file.
    preset_file = {**FOG, "stages": [{"stage": "fog", "severity": "heavy"}]}
    explicit = parse_pipeline(preset_file, "t").with_overrides(visibility_m=100.0)
    assert explicit.stages[0].params == {"visibility_m": 100.0}


def test_the_severity_override_needs_a_weather_stage():
    data = {"schema_version": 1, "variant": "x", "stages": [{"stage": "intensity", "model": "m"}]}
    with pytest.raises(ConfigError, match="--severity does not apply"):
        parse_pipeline(data, "t").with_overrides(severity="heavy")


def test_weather_settings_are_a_checked_stage_parameter():
    lisa = parse_pipeline(SNOW, "t").with_overrides(settings="lisa")
    assert lisa.stages[0].params == {"rate_mm_h": 2.5, "settings": "lisa"}
    assert lisa.config_hash() != parse_pipeline(SNOW, "t").config_hash()
    with pytest.raises(ConfigError, match="no fog model"):
        parse_pipeline(FOG, "t").with_overrides(settings="lisa")
    bad = {**SNOW, "stages": [{"stage": "snow", "rate_mm_h": 1.0, "settings": "carla"}]}
    with pytest.raises(ConfigError, match="t.yaml: stages\\[0\\]"):
        parse_pipeline(bad, "t.yaml")


def test_a_weight_file_is_recorded_by_its_absolute_path(tmp_path, monkeypatch):
    """A relative .pt path would make the tree mean another file from another folder."""
    from lads.config import load_pipeline, pipeline_for

    monkeypatch.chdir(tmp_path)
    snow = pipeline_for("semantickitti", "snow")
    given = snow.with_overrides(intensity="runs/mine.pt")
    model = next(s.params["model"] for s in given.stages if s.stage == "intensity")
    assert model == str(tmp_path / "runs" / "mine.pt")
    named = snow.with_overrides(intensity="weather")
    assert next(s.params["model"] for s in named.stages if s.stage == "intensity") == "weather"
    folder = tmp_path / "pipelines"
    folder.mkdir()
    (folder / "mine.yaml").write_text(
        "schema_version: 1\nvariant: mine\nstages:\n"
        "- {stage: snow, rate_mm_h: 2.0}\n- {stage: intensity, model: weights/w.pt}\n"
    )
    loaded = load_pipeline(folder / "mine.yaml")
    assert loaded.stages[1].params["model"] == str(folder / "weights" / "w.pt")


def test_a_weather_intensity_model_before_any_weather_is_refused_when_stages_are_built():
    from lads.stages import build_stages

    stages = [{"stage": "intensity", "model": "weather"}, {"stage": "snow", "rate_mm_h": 2.0}]
    data = {"schema_version": 1, "variant": "first", "stages": stages}
    with pytest.raises(ConfigError, match="takes its style from a rain, snow or fog stage"):
        build_stages(parse_pipeline(data, "first.yaml"))
    data["stages"] = data["stages"][::-1]
    assert len(build_stages(parse_pipeline(data, "first.yaml"))) == 2


def test_whole_pipeline_checks_name_the_file():
    snow = [{"stage": "snow", "rate_mm_h": 1.0}]
    with pytest.raises(ConfigError, match=r"^mine.yaml: writer.points is 'phys'"):
        parse_pipeline({"schema_version": 1, "variant": "x", "stages": snow,
                        "writer": {"points": "phys"}}, "mine.yaml")  # fmt: skip
    with pytest.raises(ConfigError, match=r"^mine.yaml: no 'variant' key"):
        parse_pipeline({"schema_version": 1, "stages": snow}, "mine.yaml")
