"""Sensor profiles are validated data: every shipped one loads, and bad files say what is wrong."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from lads.errors import SensorProfileError
from lads.resources import sensors_dir
from lads.sensors.profile import available_profiles, load_profile

SHIPPED = ("hdl32e", "hdl64e", "wads64")


def test_the_three_dataset_sensors_are_shipped():
    assert set(SHIPPED) <= set(available_profiles())


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_profile_is_complete_and_consistent(name):
    p = load_profile(name)
    elev = np.asarray(p.elevation_deg)
    assert elev.size == p.channels
    assert np.all(np.diff(elev) > 0), "channel 0 is the lowest beam"
    assert p.vertical_fov_deg[0] <= elev[0] and elev[-1] <= p.vertical_fov_deg[1]
    assert p.wavelength_nm == 905
    assert 0 <= p.min_range_m < p.max_range_m
    assert p.range_image_width % 4 == 0
    assert p.sources and p.elevation_method


def test_intensity_encodings_match_the_datasets():
    kitti, nusc, wads = (load_profile(n).intensity for n in ("hdl64e", "hdl32e", "wads64"))
    assert (kitti.kind, kitti.step, kitti.max_value) == ("unit", 0.01, 0.99)
    assert (nusc.kind, nusc.step, nusc.max_value) == ("byte", 1.0, 255.0)
    assert (wads.kind, wads.step, wads.max_value) == ("byte", 1.0, 255.0)
    assert load_profile("hdl32e").has_ring_column and not load_profile("hdl64e").has_ring_column


def test_encoding_round_trips_on_its_own_grid():
    enc = load_profile("hdl64e").intensity
    grid = np.round(np.arange(0, 100) * 0.01, 2).astype(np.float32)
    np.testing.assert_array_equal(enc.from_reflectivity(enc.to_reflectivity(grid)), grid)
    assert enc.from_reflectivity(np.array([5.0])).item() == pytest.approx(0.99)


def test_channel_of_picks_the_nearest_elevation():
    p = load_profile("hdl32e")
    elev = np.radians(np.asarray(p.elevation_deg))
    xyz = np.stack([10 * np.cos(elev), np.zeros_like(elev), 10 * np.sin(elev)], axis=1)
    np.testing.assert_array_equal(p.channel_of(xyz), np.arange(p.channels))


def test_unknown_profile_name_lists_the_shipped_ones():
    with pytest.raises(SensorProfileError, match="hdl64e"):
        load_profile("no_such_sensor")


def _write_variant(tmp_path: Path, **changes) -> Path:
    raw = yaml.safe_load((sensors_dir() / "hdl64e.yaml").read_text())
    raw.update(changes)
    path = tmp_path / "variant.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_copied_profile_loads_from_a_path(tmp_path):
    assert load_profile(_write_variant(tmp_path, name="mine")).name == "mine"


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"channels": 63}, "63 channels"),
        ({"range_image_width": 1023}, "multiple of 4"),
        ({"min_range_m": 500.0}, "min_range_m"),
        ({"surprise": 1}, "unknown keys"),
    ],
)
def test_invalid_profiles_name_file_and_problem(tmp_path, changes, message):
    path = _write_variant(tmp_path, **changes)
    with pytest.raises(SensorProfileError, match=message) as err:
        load_profile(path)
    assert "variant.yaml" in str(err.value)


def test_unsorted_elevations_are_rejected(tmp_path):
    raw = yaml.safe_load((sensors_dir() / "hdl64e.yaml").read_text())
    path = _write_variant(tmp_path, elevation_deg=list(reversed(raw["elevation_deg"])))
    with pytest.raises(SensorProfileError, match="strictly increasing"):
        load_profile(path)
