"""`lads build` with the learned intensity stage, on real frames, with the shipped weights."""

from __future__ import annotations

import numpy as np
import pytest

from lads.config import find_pipeline, load_pipeline
from lads.errors import ConfigError, LadsError
from lads.runner import run_build
from lads.synth import write_synthetic_dataset
from tests.trees import real_semantickitti

pytestmark = pytest.mark.usefixtures("shared_data")


def _scan(path):
    return np.fromfile(path, dtype="<f4").reshape(-1, 4)


def test_intensity_kitti_keeps_geometry_order_and_labels_and_replaces_intensity(tmp_path):
    src = real_semantickitti(tmp_path / "src")
    pipeline = load_pipeline(find_pipeline("semantickitti", "intensity-kitti"))
    out = tmp_path / "out"
    report = run_build(
        "semantickitti", src, out, pipeline, jobs=1, progress=False, limit=1, figures=False
    )
    assert report.complete
    rel = "sequences/00/velodyne/000000.bin"
    before, after = _scan(src / rel), _scan(out / rel)
    assert np.array_equal(before[:, :3], after[:, :3])  # geometry and point order
    assert (src / "sequences/00/labels/000000.label").read_bytes() == (
        out / "sequences/00/labels/000000.label"
    ).read_bytes()
    steps = after[:, 3] / 0.01
    assert np.allclose(steps, np.rint(steps), atol=1e-4) and after[:, 3].max() <= np.float32(0.99)
    assert not np.array_equal(before[:, 3], after[:, 3])


def test_the_prediction_never_reads_the_input_intensity(tmp_path):
    src = real_semantickitti(tmp_path / "src")
    rel = "sequences/00/velodyne/000000.bin"
    scrambled = tmp_path / "scrambled"
    real_semantickitti(scrambled)
    pts = _scan(src / rel).copy()
    pts[:, 3] = np.random.default_rng(0).permutation(pts[:, 3])
    (scrambled / rel).unlink()
    (scrambled / rel).write_bytes(pts.astype("<f4").tobytes())
    pipeline = load_pipeline(find_pipeline("semantickitti", "intensity-kitti"))
    for root, out in ((src, tmp_path / "a"), (scrambled, tmp_path / "b")):
        run_build(
            "semantickitti", root, out, pipeline, jobs=1, progress=False, limit=1, figures=False
        )
    assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes()


def test_intensity_physics_drops_the_learned_stage():
    snow = load_pipeline(find_pipeline("semantickitti", "snow"))
    assert [s.stage for s in snow.stages] == ["snow", "intensity"]
    physics = snow.with_overrides(intensity="physics")
    assert [s.stage for s in physics.stages] == ["snow"]
    assert physics.config_hash() != snow.config_hash()
    with pytest.raises(ConfigError, match="leaves no stage"):
        load_pipeline(find_pipeline("voxelscape", "intensity-kitti")).with_overrides(
            intensity="physics"
        )


def test_missing_weights_stop_the_build_before_any_frame(tmp_path):
    src = real_semantickitti(tmp_path / "src")
    pipeline = load_pipeline(find_pipeline("semantickitti", "intensity-kitti")).with_overrides(
        intensity=str(tmp_path / "missing.pt")
    )
    with pytest.raises(LadsError, match="missing.pt"):
        run_build(
            "semantickitti", src, tmp_path / "out", pipeline, jobs=1, progress=False, figures=False
        )
    assert not any((tmp_path / "out").rglob("*.bin"))


def test_voxelscape_sensor_adaptation_writes_nuscenes_integers(tmp_path):
    src = tmp_path / "src"
    write_synthetic_dataset(src, frames=1, layout="voxelscape", seed=2, azimuth_bins=512)
    pipeline = load_pipeline(find_pipeline("voxelscape", "intensity-nuscenes"))
    out = tmp_path / "out"
    report = run_build(
        "voxelscape", src, out, pipeline, jobs=1, progress=False, limit=1, figures=False
    )
    assert report.complete
    scans = sorted(out.rglob("velodyne/*.bin"))
    values = _scan(scans[0])[:, 3]
    assert np.array_equal(values, np.rint(values)) and values.max() <= 255


def test_snow_uses_the_weather_generator_in_the_source_encoding(tmp_path):
    src = real_semantickitti(tmp_path / "src")
    learned, physics = tmp_path / "learned", tmp_path / "physics"
    snow = load_pipeline(find_pipeline("semantickitti", "snow"))
    for pipeline, out in ((snow, learned), (snow.with_overrides(intensity="physics"), physics)):
        report = run_build(
            "semantickitti", src, out, pipeline, jobs=1, progress=False, limit=1, figures=False
        )
        assert report.complete
    rel = "sequences/00/velodyne/000000.bin"
    a, b = _scan(learned / rel), _scan(physics / rel)
    assert np.array_equal(a[:, :3], b[:, :3])  # same weather geometry, same seed
    steps = a[:, 3] / 0.01
    assert np.allclose(steps, np.rint(steps), atol=1e-4)
    assert not np.array_equal(a[:, 3], b[:, 3])
