"""`--point-format` / `writer.point_format`: each profile's native format, the setting in the
pipeline config, the readers that take another record, and what is refused, by name."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from lads.cli import EXIT_LADS_ERROR, main
from lads.config import parse_pipeline, pipeline_for
from lads.errors import ConfigError, PointFormatError
from lads.point_format import native_record, target_record
from lads.readers import READERS, get_reader, reader_class, with_columns
from lads.resources import sensors_dir
from lads.sensors.profile import available_profiles, load_profile
from lads.stages.sensor import SensorStage

NUSCENES_RECORD = ("x", "y", "z", "intensity", "ring")


@pytest.mark.parametrize("name", available_profiles())
def test_each_shipped_profile_names_the_format_its_scans_are_recorded_in(name):
    profile = load_profile(name)
    record = native_record(name)
    reader = reader_class(record.format)
    assert reader.sensor == name  # the reader of that format records this very sensor
    assert record.columns == reader.columns
    assert ("ring" in record.columns) == profile.has_ring_column


def test_the_native_formats_are_the_datasets_of_each_sensor():
    natives = {p: load_profile(p).native_format for p in available_profiles()}
    assert natives == {
        "hdl32e": "nuscenes",
        "hdl64e": "semantickitti",
        "wads64": "wads",
        "voxelscape64": "voxelscape",
    }
    assert native_record("hdl32e").columns == NUSCENES_RECORD


@pytest.mark.parametrize(("native", "message"), [(None, "names no native_format"),
                                                 ("kitti", "native_format 'kitti'")])  # fmt: skip
def test_a_profile_without_a_readable_native_format_is_refused_for_target(
    tmp_path, native, message
):
    raw = yaml.safe_load((sensors_dir() / "hdl32e.yaml").read_text())
    raw.pop("native_format")
    if native is not None:
        raw["native_format"] = native
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert load_profile(path).native_format == native  # optional: the profile loads
    with pytest.raises(PointFormatError, match=message) as err:
        native_record(str(path))
    assert "--point-format source" in str(err.value)
    stages = [{"stage": "sensor", "target": str(path)}]
    data = {"schema_version": 1, "variant": "x", "stages": stages,
            "writer": {"points": "resampled", "point_format": "target"}}  # fmt: skip
    with pytest.raises(PointFormatError, match=message):
        parse_pipeline(data, "mine-pipeline.yaml")


def test_the_default_is_the_source_record_and_leaves_the_pipeline_hash_alone():
    pipeline = pipeline_for("semantickitti", "sensor-hdl32e")
    assert pipeline.point_format == "source" and pipeline.point_record() is None
    assert "point_format" not in pipeline.to_dict()["writer"]  # older trees keep their hash
    same = pipeline.with_overrides(point_format="source")
    assert same.config_hash() == pipeline.config_hash()
    target = pipeline.with_overrides(point_format="target")
    assert target.to_dict()["writer"]["point_format"] == "target"
    assert target.config_hash() != pipeline.config_hash()
    assert target.point_record().columns == NUSCENES_RECORD
    assert parse_pipeline(target.to_dict(), "pipeline.yaml") == target  # saved, read back


@pytest.mark.parametrize(
    ("stages", "point_format", "message"),
    [
        ([{"stage": "snow", "rate_mm_h": 1.0}], "target", "no sensor stage|does not apply"),
        ([{"stage": "sensor", "target": "hdl32e"}], "native", "expected one of source, target"),
    ],
)
def test_bad_point_formats_are_refused_when_the_pipeline_is_read(stages, point_format, message):
    points = "resampled" if stages[0]["stage"] == "sensor" else "physical"
    data = {"schema_version": 1, "variant": "x", "stages": stages,
            "writer": {"points": points, "point_format": point_format}}  # fmt: skip
    with pytest.raises(PointFormatError, match=message):
        parse_pipeline(data, "test.yaml")
    assert issubclass(PointFormatError, ConfigError)


@pytest.mark.parametrize("value", ["source", "target"])
def test_the_option_is_refused_for_a_pipeline_without_a_sensor_stage(value):
    with pytest.raises(PointFormatError, match="--point-format does not apply to pipeline 'snow'"):
        pipeline_for("semantickitti", "snow").with_overrides(point_format=value)


@pytest.mark.parametrize(
    ("source", "target", "columns"),
    [
        ("semantickitti", "hdl32e", NUSCENES_RECORD),  # a .bin takes the 5 columns
        ("semantickitti", "wads64", ("x", "y", "z", "intensity")),
        ("nuscenes-kitti", "hdl64e", ("x", "y", "z", "intensity")),
    ],
)
def test_where_the_target_record_makes_sense_it_is_the_natives(source, target, columns):
    assert target_record(source, target).columns == columns
    pipeline = pipeline_for(source, f"sensor-{target}").with_overrides(point_format="target")
    pipeline.check_source(source, "test")


@pytest.mark.parametrize("target", ["hdl64e", "wads64", "voxelscape64"])
def test_a_nuscenes_tree_refuses_a_record_its_devkit_cannot_read(target):
    pipeline = pipeline_for("nuscenes", f"sensor-{target}").with_overrides(point_format="target")
    with pytest.raises(PointFormatError) as err:
        pipeline.check_source("nuscenes", "test")
    message = str(err.value)
    assert "LidarPointCloud.from_file" in message and "5 float32 columns" in message
    assert "--point-format source" in message  # what to use instead


def test_the_cli_refuses_before_anything_is_written(tmp_path):
    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    args = ["build", "--source", "nuscenes", "--in", str(src), "--out", str(out),
            "--variant", "sensor-hdl64e", "--point-format", "target"]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == EXIT_LADS_ERROR, result.output
    assert "nuscenes-devkit" in result.output and not out.exists()
    snow = ["build", "--source", "semantickitti", "--in", str(src), "--out", str(out),
            "--variant", "snow", "--point-format", "target"]  # fmt: skip
    result = CliRunner().invoke(main, snow)
    assert result.exit_code == EXIT_LADS_ERROR and "--point-format does not apply" in result.output


def test_a_sensor_stage_refuses_a_record_it_cannot_fill():
    with pytest.raises(ConfigError, match="cannot fill"):
        SensorStage("sensor", "hdl32e", columns=("x", "y", "z", "intensity", "time"))


def _lads_run_json(root: Path, sensor: str, columns: list[str]) -> None:
    run = {"lads_version": "0", "sensor": sensor, "point_columns": columns}
    (root / "run.json").write_text(json.dumps(run))


def test_a_kitti_layout_reader_takes_the_record_its_trees_run_json_names(synthetic_tree):
    root = synthetic_tree("semantickitti")
    plain = get_reader("semantickitti", root)
    item = plain.items()[0]
    frame = plain.read(item)
    ring = (np.arange(len(frame.points)) % 32).astype(np.float32)
    five = np.concatenate([frame.points, ring[:, None]], axis=1)
    writer = with_columns(plain, NUSCENES_RECORD)
    assert writer is not plain and plain.columns == READERS["semantickitti"].columns
    files = writer.encode(replace(frame, columns=NUSCENES_RECORD, points=five))
    scan = next(f for f in files if f.role == "scan")
    assert scan.record_bytes == 20
    (root / item.relpath).write_bytes(scan.payload)
    _lads_run_json(root, "hdl32e", list(NUSCENES_RECORD))
    reader = get_reader("semantickitti", root, sensor="hdl32e")
    again = reader.read(item)
    assert again.columns == NUSCENES_RECORD and again.sensor == "hdl32e"
    np.testing.assert_array_equal(again.points, five)
    with pytest.raises(ConfigError, match="pass --sensor hdl32e"):
        get_reader("semantickitti", root)  # told the dataset's own sensor: refused by name


def test_a_run_json_of_the_formats_own_record_or_not_by_lads_changes_nothing(synthetic_tree):
    root = synthetic_tree("semantickitti")
    (root / "run.json").write_text("not json: some dataset's own file")
    assert get_reader("semantickitti", root).columns == ("x", "y", "z", "intensity")
    _lads_run_json(root, "hdl64e", ["x", "y", "z", "intensity"])
    assert get_reader("semantickitti", root).columns == ("x", "y", "z", "intensity")
    _lads_run_json(root, "hdl64e", "x, y, z")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="point_columns"):
        get_reader("semantickitti", root)


def test_a_nuscenes_reader_takes_no_other_record(synthetic_tree):
    root = synthetic_tree("nuscenes")
    reader = get_reader("nuscenes", root)
    assert with_columns(reader, NUSCENES_RECORD) is reader
    with pytest.raises(PointFormatError, match="LidarPointCloud"):
        with_columns(reader, ("x", "y", "z", "intensity"))
    _lads_run_json(root, "hdl64e", ["x", "y", "z", "intensity"])
    with pytest.raises(ConfigError):
        get_reader("nuscenes", root, sensor="hdl64e")
