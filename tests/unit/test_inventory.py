"""Expected source inventories (manifests/*.yaml) and the completeness check."""

from __future__ import annotations

import pytest
import yaml

from lads import inventory as inv
from lads.errors import ConfigError

KITTI_00_10 = {"00": 4541, "01": 1101, "02": 4661, "03": 801, "04": 271, "05": 2761,
               "06": 1101, "07": 1101, "08": 4071, "09": 1591, "10": 1201}  # fmt: skip


def kitti_ids(counts: dict[str, int]) -> list[str]:
    return [
        f"semantickitti:sequences/{seq}/velodyne/{i:06d}.bin"
        for seq, n in counts.items()
        for i in range(n)
    ]


def nuscenes_ids(keyframes: int, sweeps: int = 0) -> list[str]:
    ids = [f"nuscenes:samples/LIDAR_TOP/n015__LIDAR_TOP__{i}.pcd.bin" for i in range(keyframes)]
    return ids + [f"nuscenes:sweeps/LIDAR_TOP/n015__LIDAR_TOP__{i}.pcd.bin" for i in range(sweeps)]


def test_every_shipped_inventory_loads():
    names = inv.available()
    assert {"semantickitti", "nuscenes", "voxelscape"} <= set(names)
    for name in names:
        loaded = inv.load_inventory(name)
        assert loaded.default_subset in loaded.subsets


def test_semantickitti_totals():
    assert inv.expected_counts("semantickitti", "00-10") == KITTI_00_10
    assert sum(inv.expected_counts("semantickitti", "00-10").values()) == 23201
    assert sum(inv.expected_counts("semantickitti", "11-21").values()) == 20351
    assert sum(inv.expected_counts("semantickitti", "00-21").values()) == 43552
    groups = inv.load_inventory("semantickitti").groups
    assert groups["08"].split == "validation" and groups["08"].labelled
    assert not groups["11"].labelled and groups["11"].split == "test"


def test_nuscenes_counts_and_caveats():
    assert inv.expected_counts("nuscenes", "v1.0-trainval") == {"v1.0-trainval": 34149}
    assert inv.expected_counts("nuscenes", "v1.0-mini") == {"v1.0-mini": 404}
    groups = inv.load_inventory("nuscenes").groups
    assert not groups["v1.0-mini"].verified
    assert not groups["v1.0-test"].verified and groups["v1.0-test"].approximate
    assert not groups["v1.0-test"].labelled
    assert any("unverified" in n for n in inv.notes("nuscenes", "v1.0-mini"))


def test_complete_semantickitti_release_passes():
    assert inv.compare(kitti_ids(KITTI_00_10), "semantickitti", "00-10") == []


def test_incomplete_semantickitti_release():
    counts = dict(KITTI_00_10)
    del counts["04"]
    counts["00"] -= 1
    problems = inv.compare(kitti_ids(counts), "semantickitti", "00-10")
    by_path = {path: (kind, msg) for path, kind, msg in problems}
    assert by_path["sequences/04"][0] == "incomplete_release"
    assert "04" in by_path["sequences/04"][1] and "271" in by_path["sequences/04"][1]
    assert by_path["sequences/00"][0] == "incomplete_release"
    assert "4540" in by_path["sequences/00"][1] and "4541" in by_path["sequences/00"][1]
    assert len(problems) == 2


def test_items_outside_the_subset_are_reported():
    ids = kitti_ids(KITTI_00_10) + kitti_ids({"11": 1})
    problems = inv.compare(ids, "semantickitti", "00-10")
    assert [(k, "11" in m) for _, k, m in problems] == [("inventory_extra", True)]
    stray = kitti_ids(KITTI_00_10) + ["semantickitti:elsewhere/000000.bin"]
    assert [k for _, k, _ in inv.compare(stray, "semantickitti", "00-10")] == ["inventory_extra"]


def test_nuscenes_counts_keyframes_of_the_tree_version():
    run = {"copied_files": [{"path": "v1.0-mini/sample.json", "bytes": 1, "sha256": "x"}]}
    version = inv.tree_version(run)
    assert version == "v1.0-mini"
    assert inv.compare(nuscenes_ids(404, sweeps=50), "nuscenes", "v1.0-mini", version=version) == []
    problems = inv.compare(nuscenes_ids(403), "nuscenes", "v1.0-mini", version=version)
    assert [k for _, k, _ in problems] == ["incomplete_release"]
    assert "unverified" in problems[0][2]
    wrong = inv.compare(nuscenes_ids(404), "nuscenes", "v1.0-trainval", version=version)
    assert {k for _, k, _ in wrong} == {"incomplete_release", "inventory_extra"}
    unknown = inv.compare(nuscenes_ids(404), "nuscenes", "v1.0-mini", version=None)
    assert [k for _, k, _ in unknown] == ["incomplete_release"]


def test_nuscenes_version_from_lidarseg_outputs():
    paths = ["samples/LIDAR_TOP/a.pcd.bin", "lidarseg/v1.0-trainval/tok_lidarseg.bin"]
    assert inv.tree_version({}, paths) == "v1.0-trainval"
    assert inv.tree_version({"version": "v1.0-test"}, paths) == "v1.0-test"


def test_approximate_count_accepts_one_percent():
    ok = inv.compare(nuscenes_ids(5990), "nuscenes", "v1.0-test", version="v1.0-test")
    assert ok == []
    short = inv.compare(nuscenes_ids(5000), "nuscenes", "v1.0-test", version="v1.0-test")
    assert [k for _, k, _ in short] == ["incomplete_release"]


def test_voxelscape_checks_presence_only():
    ids = [f"voxelscape:{s:02d}/velodyne/xyz_iom_000000.bin" for s in range(100)]
    ids += ["voxelscape:105/velodyne/xyz_iom_000000.bin"]  # beyond the README's 00..99
    assert inv.compare(ids, "voxelscape") == []
    missing = [i for i in ids if not i.startswith("voxelscape:57/")]
    problems = inv.compare(missing, "voxelscape")
    assert [(p, k) for p, k, _ in problems] == [("57", "incomplete_release")]
    assert any("unknown" in n for n in inv.notes("voxelscape"))


def test_group_of():
    assert inv.group_of("semantickitti:sequences/07/velodyne/000001.bin", "sequence") == "07"
    assert inv.group_of("voxelscape:12/velodyne/x.bin", "voxelscape_sequence") == "12"
    assert inv.group_of("voxelscape:sequences/12/velodyne/x.bin", "voxelscape_sequence") == "12"
    assert inv.group_of("nuscenes:samples/L/x.pcd.bin", "nuscenes_version", version="v") == "v"
    assert inv.group_of("nuscenes:sweeps/L/x.pcd.bin", "nuscenes_version", version="v") is None


def test_parse_release():
    assert inv.parse_release("semantickitti-00-10") == ("semantickitti", "00-10")
    assert inv.parse_release("nuscenes-v1.0-mini") == ("nuscenes", "v1.0-mini")
    assert inv.parse_release("voxelscape") == ("voxelscape", "all")
    with pytest.raises(ConfigError, match="no inventory"):
        inv.parse_release("kitti360-00")
    with pytest.raises(ConfigError, match="no subset"):
        inv.parse_release("semantickitti-00-99")


GOOD = {
    "schema_version": 1,
    "dataset": "toy",
    "group_by": "sequence",
    "groups": {"00": {"items": 2}, "01": {"items": 3}},
    "subsets": {"all": {"groups": ["00", "01"], "total": 5}},
    "default_subset": "all",
}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"colour": "red"}, "unknown keys"),
        ({"schema_version": 2}, "schema_version"),
        ({"dataset": "other"}, "file name"),
        ({"group_by": "season"}, "group_by"),
        ({"groups": {"00": {"items": -1}}}, "items"),
        ({"groups": {"00": {"frames": 1}}}, "groups"),
        ({"subsets": {"all": {"groups": ["00", "09"]}}}, "unknown groups"),
        ({"subsets": {"all": {"groups": ["00", "01"], "total": 6}}}, "total"),
        ({"default_subset": "most"}, "default_subset"),
    ],
)
def test_bad_inventory_files_raise_config_error(tmp_path, change, message):
    (tmp_path / "toy.yaml").write_text(yaml.safe_dump(GOOD | change))
    inv.load_inventory.cache_clear()
    with pytest.raises(ConfigError, match=message):
        inv.load_inventory("toy", tmp_path)


def test_not_yaml_or_not_a_mapping(tmp_path):
    inv.load_inventory.cache_clear()
    (tmp_path / "toy.yaml").write_text("groups: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        inv.load_inventory("toy", tmp_path)
    (tmp_path / "toy.yaml").write_text("- a list\n")
    with pytest.raises(ConfigError, match="mapping"):
        inv.load_inventory("toy", tmp_path)
    (tmp_path / "toy.yaml").write_text(yaml.safe_dump(GOOD))
    assert inv.load_inventory("toy", tmp_path).subsets == {"all": ("00", "01")}
