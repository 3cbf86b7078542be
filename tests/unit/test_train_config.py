"""Training configs find their data where the user keeps it and write where the user works."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from lads.errors import ConfigError
from lads.intensity.train_config import (
    DATA_ROOT_ENV,
    load_train_config,
    shipped_train_configs,
)
from lads.resources import train_configs_dir


def test_the_shipped_configs_are_listed():
    assert shipped_train_configs() == ["synth-to-kitti", "synth-to-nuscenes", "weather"]


def test_a_shipped_config_needs_a_data_root(monkeypatch):
    monkeypatch.delenv(DATA_ROOT_ENV, raising=False)
    with pytest.raises(ConfigError, match=f"--data-root DIR .*{DATA_ROOT_ENV}"):
        load_train_config("synth-to-kitti")


def test_a_data_root_that_does_not_exist_is_named_with_where_it_came_from(tmp_path, monkeypatch):
    monkeypatch.setenv(DATA_ROOT_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(ConfigError, match=rf"nowhere: no such folder \(\${DATA_ROOT_ENV}\)"):
        load_train_config("weather")
    with pytest.raises(ConfigError, match=r"gone: no such folder \(--data-root\)"):
        load_train_config("weather", data_root=tmp_path / "gone")


def test_relative_roots_are_taken_from_the_data_root_or_the_environment(tmp_path, monkeypatch):
    monkeypatch.delenv(DATA_ROOT_ENV, raising=False)
    for data in (tmp_path, tmp_path / "elsewhere"):
        for name in ("wads", "wads-more", "radiate"):
            (data / name / "x").mkdir(parents=True)
            (data / name / "x" / f"{name}.txt").write_text(str(data))
    cfg = load_train_config("weather", data_root=tmp_path)
    snow, fog = (p.target for p in cfg.pairs)
    assert fog.root_path() == tmp_path / "radiate"
    merged = snow.root_path()  # two roots, one view of symbolic links
    assert (merged / "x" / "wads-more.txt").read_text() == str(tmp_path)
    monkeypatch.setenv(DATA_ROOT_ENV, str(tmp_path / "elsewhere"))
    moved = load_train_config("weather")
    assert moved.pairs[1].target.root_path() == tmp_path / "elsewhere" / "radiate"
    assert moved.data_hash() == cfg.data_hash()  # where the data lives is not what it is


def test_a_user_config_takes_its_own_folder_and_writes_under_the_working_folder(
    tmp_path, monkeypatch
):
    monkeypatch.delenv(DATA_ROOT_ENV, raising=False)
    raw = {
        "schema_version": 1, "name": "mine", "kind": "sensor",
        "pairs": {"kitti": {"source": {"dataset": "synth", "frames": 1},
                            "target": {"dataset": "semantickitti", "root": "kitti"}}},
    }  # fmt: skip
    (tmp_path / "cfg").mkdir()
    path = tmp_path / "cfg" / "mine.yaml"
    path.write_text(yaml.safe_dump(raw))
    cfg = load_train_config(path)
    assert cfg.pairs[0].target.root_path() == tmp_path / "cfg" / "kitti"
    assert cfg.output_path() == Path("runs") / "mine" / "mine.pt"
    assert cfg.output_path(tmp_path / "run") == tmp_path / "run" / "mine.pt"
    raw["output"] = "w/mine.pt"
    path.write_text(yaml.safe_dump(raw))
    assert load_train_config(path).output_path() == Path("w/mine.pt")


def test_data_root_is_not_a_key_of_the_yaml(tmp_path):
    raw = {"schema_version": 1, "name": "x", "kind": "sensor",
           "pairs": {"k": {"source": {"dataset": "synth", "frames": 1},
                           "target": {"dataset": "semantickitti", "root": "/d",
                                      "data_root": "/e"}}}}  # fmt: skip
    path = tmp_path / "x.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match="unknown keys \\['data_root'\\]"):
        load_train_config(path)


def test_an_unknown_name_lists_the_shipped_configs():
    with pytest.raises(ConfigError, match="synth-to-kitti, synth-to-nuscenes, weather"):
        load_train_config("no-such-config")


def test_a_change_of_the_weather_physics_changes_the_data_hash_of_weather_models(monkeypatch):
    """Weather sources are made by the physics stage: caches and checkpoints made with
    other physics must not match (they would train on stale frames)."""
    import lads.stages.weather as stage

    weather = load_train_config(train_configs_dir() / "weather.yaml")
    sensor = load_train_config(train_configs_dir() / "synth-to-kitti.yaml")
    before = weather.data_hash(), sensor.data_hash()
    monkeypatch.setattr(stage, "WEATHER_STAGE_VERSION", stage.WEATHER_STAGE_VERSION + "x")
    assert weather.data_hash() != before[0]
    assert sensor.data_hash() == before[1]  # no weather stage: nothing to go stale


def test_the_law_input_can_be_left_out_of_a_pointwise_generator_only(tmp_path):
    text = (train_configs_dir() / "synth-to-kitti.yaml").read_text()
    good = tmp_path / "pointwise.yaml"
    good.write_text(text + "law_input: false\n")
    assert load_train_config(good, data_root=tmp_path).law_input is False
    assert load_train_config("synth-to-kitti", data_root=tmp_path).law_input is True
    unet = text.replace("architecture: pointwise", "architecture: unet")
    unet = unet.replace("identity_points: 8192", "")
    bad = tmp_path / "unet.yaml"
    bad.write_text(unet + "law_input: false\n")
    with pytest.raises(ConfigError, match="law_input: false needs architecture: pointwise"):
        load_train_config(bad, data_root=tmp_path)
    bad.write_text(text + "law_input: maybe\n")
    with pytest.raises(ConfigError, match="law_input = 'maybe'"):
        load_train_config(bad, data_root=tmp_path)
