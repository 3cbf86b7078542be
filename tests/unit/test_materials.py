"""Material reflectance per class label: lads/physics/materials.{yaml,py}.

See docs/physics.md §10.2."""

from __future__ import annotations

import copy
import importlib.resources
import warnings

import numpy as np
import pytest
import yaml

from lads.errors import ConfigError, InputDataError
from lads.physics import materials
from lads.physics.materials import (
    LABEL_SETS,
    UnknownLabelWarning,
    class_materials,
    material_table,
    parse_table,
    reflectance_for_labels,
)

# docs/physics.md §10.2, SemanticKITTI class -> material table, written out as the specification.
KITTI_TABLE = {
    **dict.fromkeys((0, 1, 99), 0.20),
    **dict.fromkeys((10, 11, 13, 15, 16, 18, 20, 252, 256, 257, 258, 259), 0.52),
    **dict.fromkeys((30, 31, 32, 253, 254, 255), 0.60),
    40: 0.10, 44: 0.10, 48: 0.35, 52: 0.35, 49: 0.30, 50: 0.30, 51: 0.32, 60: 0.60,
    70: 0.49, 71: 0.33, 72: 0.55, 80: 0.75, 81: 1.00,
}  # fmt: skip
VOXELSCAPE_RENAMED = (16, 20, 30, 49, 52, 99, 252, 253, 254, 255, 256, 257, 258, 259)


@pytest.fixture
def fresh_warnings(monkeypatch):
    """Forget which unknown ids were already reported, so each test sees its own warnings."""
    monkeypatch.setattr(materials, "_warned", {})


def _raw_yaml() -> dict:
    text = importlib.resources.files("lads.physics").joinpath("materials.yaml").read_text()
    return yaml.safe_load(text)


@pytest.mark.parametrize(("class_id", "rho"), sorted(KITTI_TABLE.items()))
def test_every_semantickitti_class_gets_its_physics_table_value(class_id, rho):
    out = reflectance_for_labels(np.array([class_id], dtype=np.uint32), "semantickitti")
    assert out.dtype == np.float32 and out.shape == (1,)
    assert out[0] == pytest.approx(rho)


def test_semantickitti_map_covers_exactly_the_34_raw_ids():
    assert set(class_materials("semantickitti")) == set(KITTI_TABLE)


def test_instance_bits_are_ignored():
    classes = np.array(sorted(KITTI_TABLE), dtype=np.uint32)
    with_instances = (np.arange(1, len(classes) + 1, dtype=np.uint32) * 4099 << 16) | classes
    for label_set in ("semantickitti", "voxelscape", "wads"):
        np.testing.assert_array_equal(
            reflectance_for_labels(with_instances, label_set),
            reflectance_for_labels(classes, label_set),
        )


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.uint32, np.int64, np.uint64])
def test_any_integer_dtype_is_accepted(dtype):
    out = reflectance_for_labels(np.array([40, 50, 70], dtype=dtype), "semantickitti")
    np.testing.assert_allclose(out, [0.10, 0.30, 0.49])


def test_voxelscape_curb_is_concrete_not_other_vehicle_paint():
    assert reflectance_for_labels(np.array([20]), "voxelscape")[0] == pytest.approx(0.35)
    assert reflectance_for_labels(np.array([20]), "semantickitti")[0] == pytest.approx(0.52)


def test_voxelscape_renamed_ids_have_their_own_classes():
    vox, kitti = class_materials("voxelscape"), class_materials("semantickitti")
    assert vox[49] == ("crosswalk", "paint_white")
    assert vox[16][1] == vox[30][1] == "fabric_clothing"
    for class_id in VOXELSCAPE_RENAMED:
        assert vox[class_id][0] != kitti[class_id][0]


def test_voxelscape_keeps_the_20_shared_semantickitti_classes():
    vox, kitti = class_materials("voxelscape"), class_materials("semantickitti")
    shared = set(kitti) - set(VOXELSCAPE_RENAMED)
    assert len(shared) == 20 and set(vox) == set(kitti)
    assert all(vox[i] == kitti[i] for i in shared)


def test_wads_adds_bright_snow_to_semantickitti():
    wads, kitti = class_materials("wads"), class_materials("semantickitti")
    assert set(wads) == set(kitti) | {110, 111}
    assert all(wads[i] == kitti[i] for i in kitti)
    snow = reflectance_for_labels(np.array([110, 111]), "wads")
    assert np.all((snow >= 0.8) & (snow <= 0.95))


def test_nuscenes_maps_all_32_lidarseg_indices_without_instance_masking(fresh_warnings):
    nus = class_materials("nuscenes")
    assert sorted(nus) == list(range(32))
    assert nus[24] == ("flat.driveable_surface", "asphalt")
    assert nus[26][0] == "flat.sidewalk" and nus[27][0] == "flat.terrain"  # alphabetical order
    out = reflectance_for_labels(np.arange(32, dtype=np.uint8), "nuscenes")
    assert out[17] == pytest.approx(0.52) and out[30] == pytest.approx(0.49)
    assert out[0] == out[31] == pytest.approx(0.20)  # noise, ego
    with pytest.warns(UnknownLabelWarning):
        out = reflectance_for_labels(np.array([(1 << 16) | 17]), "nuscenes")
    assert out[0] == pytest.approx(0.2)


def test_unknown_ids_get_the_default_and_warn_once_per_new_id(fresh_warnings):
    labels = np.array([40, 1000, 1001, 1000], dtype=np.uint32)
    with pytest.warns(UnknownLabelWarning, match=r"\[1000, 1001\]") as record:
        out = reflectance_for_labels(labels, "semantickitti")
    assert len(record) == 1
    np.testing.assert_allclose(out, [0.10, 0.20, 0.20, 0.20])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reflectance_for_labels(labels, "semantickitti")  # same ids: silent
    with pytest.warns(UnknownLabelWarning, match=r"\[1002\]"):
        reflectance_for_labels(np.array([1000, 1002]), "semantickitti")
    with pytest.warns(UnknownLabelWarning, match="'wads'"):  # counted per label set
        reflectance_for_labels(np.array([1000]), "wads")


def test_unknown_label_set_lists_the_known_ones():
    with pytest.raises(ConfigError, match="semantickitti, nuscenes, voxelscape, wads"):
        reflectance_for_labels(np.array([1]), "kitti")


@pytest.mark.parametrize(
    "labels",
    [np.array([10, -1]), np.array([[10, 40]]), np.array([10.0, 40.0]), np.array(["car"])],
)
def test_bad_labels_raise_input_data_error(labels):
    with pytest.raises(InputDataError):
        reflectance_for_labels(labels, "semantickitti")


def test_empty_labels_give_an_empty_float32_array():
    out = reflectance_for_labels(np.array([], dtype=np.uint32), "semantickitti")
    assert out.shape == (0,) and out.dtype == np.float32


def test_table_is_valid_and_every_value_cited():
    table = material_table()
    assert LABEL_SETS == ("semantickitti", "nuscenes", "voxelscape", "wads")
    assert table["unknown"].reflectance == pytest.approx(0.20)
    for material in table.values():
        assert 0.0 <= material.reflectance <= 1.2 and material.source
    for label_set in LABEL_SETS:
        assert {m for _, m in class_materials(label_set).values()} <= set(table)


def test_material_table_returns_a_copy():
    material_table().clear()
    assert material_table()


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda r: r["label_sets"]["wads"]["classes"].__setitem__(
                110, {"name": "snow", "material": "powder"}
            ),
            "unknown material 'powder'",
        ),
        (lambda r: r["materials"]["tar"].__setitem__("reflectance", 1.5), "0 <= rho <= 1.2"),
        (lambda r: r["materials"]["tar"].__setitem__("source", ""), "must cite"),
        (lambda r: r["label_sets"].pop("wads"), "label_sets must be exactly"),
        (lambda r: r.__setitem__("colour", 1), "unknown keys"),
        (
            lambda r: r["label_sets"]["nuscenes"]["classes"].__setitem__(
                70000, {"name": "x", "material": "tar"}
            ),
            "outside",
        ),
        (lambda r: r["materials"]["tar"].__setitem__("finish", "matte"), "finish = 'matte'"),
        (
            lambda r: r["label_sets"]["nuscenes"]["classes"][24].__setitem__("flat", True),
            "drop `flat`",
        ),
    ],
)
def test_invalid_tables_raise_config_error_naming_the_file(edit, message):
    raw = copy.deepcopy(_raw_yaml())
    edit(raw)
    with pytest.raises(ConfigError, match=message) as info:
        parse_table(raw, "materials.yaml")
    assert str(info.value).startswith("materials.yaml")


def test_instance_bits_are_read_from_the_label_sets():
    from lads.intensity.evaluate import class_ids
    from lads.physics.materials import has_instance_bits

    assert has_instance_bits("semantickitti") and not has_instance_bits("nuscenes")
    labels = np.array([(7 << 16) | 10, 40], dtype=np.uint32)
    np.testing.assert_array_equal(class_ids(labels, "semantickitti"), [10, 40])
    np.testing.assert_array_equal(class_ids(np.array([17, 24]), "nuscenes"), [17, 24])
    with pytest.raises(ConfigError, match="unknown label set"):
        has_instance_bits("kitti360")


def test_surface_roles_follow_the_materials_of_every_label_set():
    """Glossy paint, retro-reflectors and road-like ground are read from materials.yaml, so a
    label set names them by its own ids (nuScenes cones and flat.* included)."""
    from lads.physics.materials import LABEL_SETS, class_materials, class_roles

    kitti = class_roles("semantickitti")
    assert {10, 18, 252} <= kitti.clearcoat and 30 not in kitti.clearcoat
    assert kitti.retroreflective == {81}
    assert kitti.road_like == {40, 44, 48, 49, 60}
    assert kitti.level_ground == kitti.road_like | {72}
    nusc = class_roles("nuscenes")
    assert nusc.retroreflective == {12}  # movable_object.trafficcone
    assert nusc.road_like == {24, 25, 26} and nusc.level_ground == {24, 25, 26, 27}
    assert 31 not in nusc.clearcoat  # the ego vehicle's own body is not a painted target
    assert 256 in class_roles("voxelscape").retroreflective  # construction-cone
    for name in LABEL_SETS:
        roles, names = class_roles(name), class_materials(name)
        for cid in roles.clearcoat:
            assert names[cid][1] == "paint_vehicle"
        assert roles.road_like <= roles.level_ground <= set(names)
