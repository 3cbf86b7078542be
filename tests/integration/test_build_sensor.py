"""`lads build --variant sensor-<profile>`: a sequence ray-cast again with another sensor,
one output frame per source frame, in the source's format, with provenance to the source
return behind every output point; the window, the variant names and bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lads import provenance
from lads.config import parse_pipeline, pipeline_for, variants_for
from lads.errors import ConfigError
from lads.physics.result import Outcome
from lads.readers import get_reader
from lads.runner import run_build
from lads.sensors.profile import load_profile
from lads.synth.writer import write_synthetic_dataset
from lads.transfer.blend import MIN_TOL_COS
from lads.transfer.window import DEFAULT_NEIGHBOURS, window_of
from lads.verify import verify_tree
from lads.worker import stages_for

FRAMES = 4


@pytest.fixture(scope="module")
def street(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-frame HDL-64E street in the SemanticKITTI layout, with poses.txt and calib.txt."""
    root = tmp_path_factory.mktemp("street") / "src"
    write_synthetic_dataset(root, frames=FRAMES)
    return root


@pytest.fixture(scope="module")
def built(street: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sensor") / "out"
    report = run_build(
        "semantickitti",
        street,
        out,
        pipeline_for("semantickitti", "sensor-hdl32e"),
        jobs=1,
        progress=False,
        figures=False,
    )
    assert report.complete, report.failed
    return out


def test_every_profile_but_the_sources_own_is_a_sensor_variant():
    assert "sensor-hdl32e" in variants_for("semantickitti")
    assert "sensor-hdl64e" not in variants_for("semantickitti")
    assert "sensor-hdl64e" in variants_for("nuscenes-kitti")
    assert not [v for v in variants_for("wads") if v.startswith("sensor")]  # no poses
    pipeline = pipeline_for("nuscenes-kitti", "sensor-wads64")
    assert pipeline.variant == "sensor-wads64" and pipeline.points == "resampled"
    assert pipeline.stages[0].params["target"] == "wads64"
    assert pipeline.output_sensor("hdl32e") == "wads64"


def test_the_transferred_tree_verifies_and_regenerates(built: Path, street: Path):
    check = verify_tree(built, street, regenerate=2, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]


def test_output_is_the_targets_scan_in_the_sources_format(built: Path, street: Path):
    target = load_profile("hdl32e")
    with pytest.raises(ConfigError, match="pass --sensor hdl32e"):
        get_reader("semantickitti", built)  # its points are the HDL-32E's, not the format's
    reader = get_reader("semantickitti", built, sensor="hdl32e")
    for item in reader.items():
        frame = reader.read(item)
        assert frame.labels is not None and len(frame.labels) == len(frame.points) > 1000
        xyz = frame.xyz.astype(np.float64)
        el = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
        nearest = np.abs(el[:, None] - np.asarray(target.elevation_deg)[None]).min(axis=1)
        assert np.median(nearest) < 0.05  # on the target's beams (range noise moves a few)
        step = target.intensity.step
        assert np.allclose(frame.intensity / step, np.rint(frame.intensity / step), atol=1e-3)


def test_provenance_names_the_source_return_each_beam_hit(built: Path, street: Path):
    """Every output point lies on the surfel of the source return its provenance names: that
    return, moved into the output frame with the two scans' poses, is within a surfel's
    reach, and its label is the output point's."""
    reader = get_reader("semantickitti", street)
    items = {it.relpath: it for it in reader.items()}
    poses = reader.sensor_poses(list(items.values()))
    stage = stages_for(pipeline_for("semantickitti", "sensor-hdl32e"))[0]
    for rel in sorted(items)[:2]:
        out = get_reader("semantickitti", built, sensor="hdl32e").read(items[rel])
        source_index, outcome, attrs = provenance.read_item(built, rel)
        window, scans = provenance.read_source_scan(built, rel)
        assert (outcome == Outcome.RESAMPLED).all() and rel in window and len(window) == FRAMES
        assert scans.size == len(out.points) and set(np.unique(scans)) <= set(range(len(window)))
        assert (scans != window.index(rel)).any()  # the neighbours lend surfaces
        for k, wrel in enumerate(window):
            mine = scans == k
            src = reader.read(items[wrel])
            to_out = np.linalg.inv(poses[rel]) @ poses[wrel]
            surfels = stage.prepare(src).surfels
            row = np.searchsorted(surfels.point, source_index[mine])
            assert (surfels.point[row] == source_index[mine]).all()  # a return with a surfel
            centre = surfels.centre[row] @ to_out[:3, :3].T + to_out[:3, 3]
            normal = surfels.normal[row] @ to_out[:3, :3].T
            xyz = out.xyz[mine].astype(np.float64)
            range_m = np.linalg.norm(xyz, axis=1)
            beam = xyz / range_m[:, None]
            t_own = np.einsum("ij,ij->i", centre, normal) / np.einsum("ij,ij->i", beam, normal)
            # The beam meets the named surfel inside its ellipse ...
            gap = np.linalg.norm(beam * t_own[:, None] - centre, axis=1)
            assert (gap <= surfels.radius_m[row] * (1 + 1e-6) + 1e-4).all()
            # ... and the range is the blend of the hits within the cast's depth window
            # behind the beam's nearest hit (lads.transfer.cast), widest at grazing incidence.
            window_m = np.maximum(0.1, 0.01 * np.maximum(range_m, t_own)) / MIN_TOL_COS
            assert (np.abs(range_m - t_own) <= window_m + 5 * 0.02).all()
            assert np.median(np.abs(range_m - t_own)) < 0.03
            assert (src.labels[source_index[mine]] == out.labels[mine]).all()


def test_output_bytes_do_not_depend_on_the_job_count(built: Path, street: Path, tmp_path):
    out = tmp_path / "two"
    run_build(
        "semantickitti",
        street,
        out,
        pipeline_for("semantickitti", "sensor-hdl32e"),
        jobs=2,
        progress=False,
        figures=False,
    )
    for item in get_reader("semantickitti", street).items():
        for rel in item.source_relpaths():
            assert (out / rel).read_bytes() == (built / rel).read_bytes()


def test_missing_poses_fail_each_frame_by_name_and_neighbours_0_needs_none(street, tmp_path):
    src = tmp_path / "src"
    shutil.copytree(street, src)
    (src / "sequences" / "00" / "poses.txt").unlink()
    pipeline = pipeline_for("semantickitti", "sensor-hdl32e")
    report = run_build(
        "semantickitti",
        src,
        tmp_path / "a",
        pipeline,
        jobs=1,
        progress=False,
        figures=False,
        limit=1,
    )
    assert len(report.failed) == 1 and "poses.txt" in report.failed[0][1]
    assert "--neighbours 0" in report.failed[0][1]
    (src / "sequences" / "00" / "calib.txt").rename(tmp_path / "calib.txt")
    report = run_build(
        "semantickitti", src, tmp_path / "c", pipeline, jobs=1, progress=False, limit=1
    )
    assert "no poses.txt and no calib.txt" in report.failed[0][1]
    (tmp_path / "calib.txt").rename(src / "sequences" / "00" / "calib.txt")
    alone = pipeline.with_overrides(neighbours=0)
    report = run_build(
        "semantickitti", src, tmp_path / "b", alone, jobs=1, progress=False, figures=False, limit=1
    )
    assert report.complete
    window, scans = provenance.read_source_scan(tmp_path / "b", "sequences/00/velodyne/000000.bin")
    assert window == ["sequences/00/velodyne/000000.bin"] and not scans.any()


@pytest.mark.parametrize(
    ("stages", "points", "message"),
    [
        ([{"stage": "sensor", "target": "hdl32e"}], "physical", "resampled"),
        ([{"stage": "snow", "rate_mm_h": 1.0}], "resampled", "only a sensor stage"),
        (
            [{"stage": "sensor", "target": "hdl32e"}, {"stage": "snow", "rate_mm_h": 1.0}],
            "resampled",
            "must come first",
        ),
        ([{"stage": "sensor", "target": "no-such-lidar"}], "resampled", "no-such-lidar"),
        ([{"stage": "sensor", "target": "hdl32e", "neighbours": -1}], "resampled", "0..200"),
    ],
)
def test_bad_sensor_pipelines_are_refused_by_name(stages, points, message):
    data = {"schema_version": 1, "variant": "x", "stages": stages, "writer": {"points": points}}
    with pytest.raises(ConfigError, match=message):
        parse_pipeline(data, "test.yaml")


def _position(item: tuple[str, int]) -> tuple[str, int]:
    return item


@pytest.mark.parametrize(
    ("held", "centre", "neighbours", "want"),
    [
        (range(100), 50, 10, range(45, 56)),  # half before, half after
        (range(100), 50, 3, range(49, 53)),  # the odd one after
        (range(100), 0, 10, range(0, 11)),  # moved inside at the start ...
        (range(100), 99, 10, range(89, 100)),  # ... and at the end
        (range(5), 2, 10, range(0, 5)),  # a short sequence: all of it
        ([0, 52, 88, 850], 52, 10, [52]),  # isolated frames: each alone
        ([0, 3, 5, 9, 12], 5, 10, [0, 3, 5, 9]),  # gaps in the span are absent
    ],
)
def test_the_window_spans_neighbours_around_the_frame_inside_the_sequence(
    held, centre, neighbours, want
):
    items = [("00", n) for n in held] + [("01", n) for n in range(100)]
    window, k = window_of(items, ("00", centre), neighbours, _position)
    assert [n for _, n in window] == list(want) and window[k] == ("00", centre)
    assert {s for s, _ in window} == {"00"}


def test_further_per_point_arrays_follow_the_return_each_beam_hit(street: Path):
    """nuScenes panoptic and the like: each beam takes the value of the source row it hit,
    in the scan that row belongs to."""
    from dataclasses import replace

    reader = get_reader("semantickitti", street)
    items = reader.items()[:2]
    frames = [reader.read(it) for it in items]
    frames = [
        replace(f, extra_labels={"row": np.arange(len(f.points), dtype=np.uint32)}) for f in frames
    ]
    poses = reader.sensor_poses(items)
    stage = stages_for(pipeline_for("semantickitti", "sensor-hdl32e"))[0]
    parts = [stage.prepare(f) for f in frames]
    window = tuple(it.relpath for it in items)
    out = stage.call_window(
        frames[0], parts, [poses[r] for r in window], 0, window, np.random.default_rng(0)
    )
    assert (out.extra_labels["row"] == out.source_index).all()
    assert set(np.unique(out.source_scan)) == {0, 1}


def test_a_nuscenes_dataroot_transfers_with_its_ego_poses(tmp_path):
    """nuScenes tables: lidar -> global = ego_pose x calibrated_sensor; the scene's keyframes
    in time order make the window; the devkit reads the transferred dataroot back."""
    from nuscenes.nuscenes import NuScenes

    src = tmp_path / "src"
    write_synthetic_dataset(src, frames=3, layout="nuscenes")
    reader = get_reader("nuscenes", src)
    items = reader.items()
    assert [reader.scan_position(it)[1] for it in items] == [0, 1, 2]  # by timestamp
    poses = reader.sensor_poses(items)
    assert not np.allclose(poses[items[0].relpath], poses[items[2].relpath])  # it drives
    out = tmp_path / "out"
    report = run_build(
        "nuscenes",
        src,
        out,
        pipeline_for("nuscenes", "sensor-hdl64e"),
        jobs=1,
        progress=False,
        figures=False,
    )
    assert report.complete, report.failed
    check = verify_tree(out, src, regenerate=1, seed=0)
    assert check.ok, [f"{p.kind} {p.path}: {p.message}" for p in check.problems]
    nusc = NuScenes(version="v1.0-mini", dataroot=str(out), verbose=False)
    for sample in nusc.sample:
        sd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
        raw = np.fromfile(out / sd["filename"], dtype="<f4").reshape(-1, 5)
        labels = np.fromfile(out / nusc.get("lidarseg", sd["token"])["filename"], dtype=np.uint8)
        assert labels.size == len(raw) > 60_000 and np.isin(raw[:, 4], np.arange(64)).all()


def test_a_learned_intensity_may_follow_the_transfer():
    stages = [{"stage": "sensor", "target": "hdl32e"},
              {"stage": "intensity", "model": "synth-to-nuscenes"}]  # fmt: skip
    data = {
        "schema_version": 1,
        "variant": "x",
        "stages": stages,
        "writer": {"points": "resampled"},
    }
    pipeline = parse_pipeline(data, "test.yaml")
    assert [s.stage for s in pipeline.stages] == ["sensor", "intensity"]
    assert pipeline.output_sensor("hdl64e") == "hdl32e"


def test_weather_on_a_transferred_tree_uses_the_target_sensor(built: Path, tmp_path):
    """A second build whose source is the transferred tree, told its sensor (`--sensor`)."""
    import json

    pipeline = pipeline_for("semantickitti", "snow").with_overrides(intensity="physics")
    out = tmp_path / "snow"
    report = run_build(
        "semantickitti",
        built,
        out,
        pipeline,
        reader_options={"sensor": "hdl32e"},
        jobs=1,
        progress=False,
        figures=False,
        limit=2,
    )
    assert report.complete, report.failed
    assert json.loads((out / "run.json").read_text())["sensor"] == "hdl32e"
    frame = get_reader("semantickitti", built, sensor="hdl32e").read(
        get_reader("semantickitti", built, sensor="hdl32e").items()[0]
    )
    assert frame.sensor == "hdl32e"
    with pytest.raises(ConfigError, match="no-such-lidar"):
        get_reader("semantickitti", built, sensor="no-such-lidar")


def _build_32(src: Path, out: Path, **overrides: object) -> object:
    pipeline = pipeline_for("semantickitti", "sensor-hdl32e").with_overrides(**overrides)
    return run_build("semantickitti", src, out, pipeline, jobs=1, progress=False, figures=False)


def test_changed_poses_are_a_changed_source_to_verify_and_resume(street: Path, tmp_path: Path):
    src, out = tmp_path / "src", tmp_path / "out"
    shutil.copytree(street, src)
    assert _build_32(src, out).complete  # type: ignore[attr-defined]
    rows = [r for r in map(json.loads, (out / "manifest.jsonl").read_text().splitlines())]
    assert all(
        {"sequences/00/poses.txt", "sequences/00/calib.txt"} <= {s["path"] for s in r["source"]}
        for r in rows
    )
    poses = src / "sequences" / "00" / "poses.txt"
    lines = poses.read_text().splitlines()
    fields = lines[2].split()
    fields[3] = repr(float(fields[3]) + 0.5)  # scan 2 placed half a metre further along x
    lines[2] = " ".join(fields)
    poses.write_text("\n".join(lines) + "\n")
    check = verify_tree(out, src)
    assert not check.ok
    kinds = {p.kind for p in check.problems}
    assert kinds == {"source_changed", "copied_file_differs"}, check.problems
    report = _build_32(src, out)
    assert report.built == FRAMES and report.skipped == 0  # type: ignore[attr-defined]
    assert verify_tree(out, src, regenerate=1, seed=0).ok


def test_a_frame_without_neighbours_in_the_tree_needs_no_poses(street: Path, tmp_path: Path):
    src = tmp_path / "src"
    shutil.copytree(street, src)
    seq = src / "sequences" / "00"
    (seq / "poses.txt").unlink()
    far = 3 + 2 * DEFAULT_NEIGHBOURS  # beyond every other scan's window
    for sub, ext in (("velodyne", "bin"), ("labels", "label")):
        (seq / sub / f"000003.{ext}").rename(seq / sub / f"{far:06d}.{ext}")
    rel = f"sequences/00/velodyne/{far:06d}.bin"
    report = _build_32(src, tmp_path / "window")
    assert [i for i, _ in report.failed] == [  # type: ignore[attr-defined]
        f"semantickitti:sequences/00/velodyne/{k:06d}.bin" for k in range(3)
    ]
    _build_32(src, tmp_path / "alone", neighbours=0)
    assert (tmp_path / "window" / rel).read_bytes() == (tmp_path / "alone" / rel).read_bytes()
    row = next(
        r
        for r in map(json.loads, (tmp_path / "window" / "manifest.jsonl").read_text().splitlines())
        if r["item_id"].endswith(rel)
    )
    assert [s["path"] for s in row["source"]] == [
        rel,
        rel.replace("velodyne", "labels")[:-3] + "label",
    ]


def test_scans_named_without_a_number_fail_alone(street: Path, tmp_path: Path):
    """A browser's `000000 (1).bin` has no place in time, a macOS `._000001.bin` is no scan:
    each fails as its own item, named, and every other frame transfers."""
    src = tmp_path / "src"
    shutil.copytree(street, src)
    seq = src / "sequences" / "00"
    shutil.copy(seq / "velodyne" / "000000.bin", seq / "velodyne" / "000000 (1).bin")
    shutil.copy(seq / "labels" / "000000.label", seq / "labels" / "000000 (1).label")
    (seq / "velodyne" / "._000001.bin").write_bytes(b"\0" * 4096)
    (seq / "labels" / "._000001.label").write_bytes(b"\0" * 1024)
    report = _build_32(src, tmp_path / "out")
    failed = dict(report.failed)  # type: ignore[attr-defined]
    assert report.built == FRAMES  # type: ignore[attr-defined]
    assert "is not its number" in failed["semantickitti:sequences/00/velodyne/000000 (1).bin"]
    assert "macOS metadata file" in failed["semantickitti:sequences/00/velodyne/._000001.bin"]


def test_weather_whose_learned_intensity_lacks_the_sensor_is_refused_before_any_frame(
    street: Path, tmp_path: Path
):
    transferred = tmp_path / "vx"
    pipeline = pipeline_for("semantickitti", "sensor-voxelscape64")
    run_build("semantickitti", street, transferred, pipeline, progress=False, limit=1)
    snow = tmp_path / "snow"
    with pytest.raises(ConfigError, match="no calibration for sensor 'voxelscape64'"):
        run_build(
            "semantickitti",
            transferred,
            snow,
            pipeline_for("semantickitti", "snow"),
            reader_options={"sensor": "voxelscape64"},
            progress=False,
        )
    assert not snow.exists()
    physics = pipeline_for("semantickitti", "snow").with_overrides(intensity="physics")
    report = run_build(
        "semantickitti",
        transferred,
        snow,
        physics,
        reader_options={"sensor": "voxelscape64"},
        progress=False,
    )
    assert report.complete, report.failed


def test_intensities_of_another_encoding_fail_each_frame_by_name(street: Path, tmp_path: Path):
    """0-255 codes read as an HDL-64E's 0-0.99 remission would all become albedo 0.99."""
    src = tmp_path / "src"
    shutil.copytree(street, src)
    for scan in (src / "sequences" / "00" / "velodyne").glob("*.bin"):
        points = np.fromfile(scan, "<f4").reshape(-1, 4)
        points[:, 3] = np.rint(points[:, 3] * 255.0)
        points.tofile(scan)
    report = _build_32(src, tmp_path / "out", neighbours=0)
    assert report.built == 0  # type: ignore[attr-defined]
    assert all("IntensityEncodingError" in e for _, e in report.failed)  # type: ignore[attr-defined]
