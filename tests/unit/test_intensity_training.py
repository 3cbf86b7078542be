"""`lads train`: config validation, the resumable zarr cache, checkpoints and resume."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lads.errors import ConfigError, TrainingError
from lads.intensity.cache import build_cache, list_jobs
from lads.intensity.checkpoint import load_model
from lads.intensity.train import CHECKPOINT, train
from lads.intensity.train_config import parse_train_config
from lads.synth import write_synthetic_dataset

PNG = b"\x89PNG\r\n\x1a\n"


def _config(target_root: Path, output: Path, **changes) -> dict:
    raw = {
        "schema_version": 1,
        "name": "tiny",
        "kind": "sensor",
        "output": str(output),
        "pairs": {
            "kitti": {
                "source": {"dataset": "synth", "sensor": "hdl64e", "frames": 2, "seed": 4,
                           "azimuth_bins": 256},  # fmt: skip
                "target": {"dataset": "semantickitti", "root": str(target_root),
                           "holdout": ["sequences/00/velodyne/000002.bin"]},  # fmt: skip
            }
        },
        "steps": 4, "batch": 2, "crop_width": 64, "base": 4, "blocks": 1, "disc_base": 4,
        "checkpoint_every": 2, "workers": 1, "seed": 3,
    }  # fmt: skip
    raw.update(changes)
    return raw


@pytest.fixture(scope="module")
def target_tree(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("kitti-like")
    write_synthetic_dataset(root, sensor="hdl64e", frames=3, layout="semantickitti", seed=9,
                            progress=False, azimuth_bins=256)  # fmt: skip
    return root


def test_held_out_frames_never_enter_the_cache(target_tree, tmp_path):
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")
    frames = {j.frame for j in list_jobs(cfg) if j.role == "target"}
    assert "sequences/00/velodyne/000002.bin" not in frames and len(frames) == 2


def test_a_holdout_that_matches_nothing_is_an_error(target_tree, tmp_path):
    raw = _config(target_tree, tmp_path / "w.pt")
    raw["pairs"]["kitti"]["target"]["holdout"] = ["sequences/00/velodyne/999999.bin"]
    with pytest.raises(TrainingError, match="999999"):
        list_jobs(parse_train_config(raw, "test"))


def test_unknown_keys_and_bad_weather_pairs_are_config_errors(target_tree, tmp_path):
    with pytest.raises(ConfigError, match="unknown keys"):
        parse_train_config(_config(target_tree, tmp_path / "w.pt", learning_rate=1), "t")
    with pytest.raises(ConfigError, match="style"):
        parse_train_config(_config(target_tree, tmp_path / "w.pt", kind="weather"), "t")


def test_the_cache_is_built_once_and_resumes(target_tree, tmp_path):
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")
    jobs = build_cache(tmp_path, cfg, progress=False)
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "cache.zarr").rglob("zarr.json")}
    build_cache(tmp_path, cfg, progress=False)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps  # nothing rebuilt
    # A frame whose completion mark is missing (killed mid-write) is rebuilt.
    victim = tmp_path / "cache.zarr" / jobs[0].node / "zarr.json"
    victim.write_text(victim.read_text().replace('"done": true', '"done": false'))
    build_cache(tmp_path, cfg, progress=False)
    assert '"done": true' in victim.read_text()


def test_training_writes_weights_loss_figure_and_checkpoint(target_tree, tmp_path):
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")
    summary = train(cfg, run_dir=tmp_path / "run", progress=False)
    assert summary["steps_done"] == 4
    model = load_model(tmp_path / "w.pt")
    assert model.meta.targets["kitti"].sensor == "hdl64e"
    assert model.meta.training["steps"] == 4
    assert (tmp_path / "run" / "loss.png").read_bytes().startswith(PNG)
    assert (tmp_path / "run" / CHECKPOINT).is_file()


def test_an_interrupted_run_resumes_to_the_same_weights(target_tree, tmp_path):
    cfg = parse_train_config(_config(target_tree, tmp_path / "a.pt"), "test")
    train(cfg, run_dir=tmp_path / "a", progress=False)
    other = dataclasses.replace(cfg, output=str(tmp_path / "b.pt"))
    stopped = train(other, run_dir=tmp_path / "b", progress=False, max_steps=2)
    assert stopped["steps_done"] == 2 and not (tmp_path / "b.pt").exists()
    train(other, run_dir=tmp_path / "b", progress=False)
    a, b = load_model(tmp_path / "a.pt"), load_model(tmp_path / "b.pt")
    for (name, ta), (_, tb) in zip(a.generator.state_dict().items(),
                                   b.generator.state_dict().items(), strict=True):  # fmt: skip
        assert ta.equal(tb), name


def test_a_checkpoint_of_another_config_is_refused(target_tree, tmp_path):
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")
    train(cfg, run_dir=tmp_path / "run", progress=False, max_steps=2)
    changed = dataclasses.replace(cfg, lr=1e-3)
    with pytest.raises(TrainingError, match="another config"):
        train(changed, run_dir=tmp_path / "run", progress=False)
