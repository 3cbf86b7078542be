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
                "source": {
                    "dataset": "synth",
                    "sensor": "hdl64e",
                    "frames": 2,
                    "seed": 4,
                    "azimuth_bins": 256,
                },
                "target": {
                    "dataset": "semantickitti",
                    "root": str(target_root),
                    "split": {
                        "train": ["sequences/00/velodyne/00000[01].bin"],
                        "validation": ["sequences/00/velodyne/000002.bin"],
                    },
                },
            }
        },
        "steps": 4,
        "batch": 2,
        "crop_width": 64,
        "base": 4,
        "blocks": 1,
        "disc_base": 4,
        "checkpoint_every": 2,
        "workers": 1,
        "seed": 3,
    }
    raw.update(changes)
    return raw


@pytest.fixture(scope="module")
def target_tree(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("kitti-like")
    write_synthetic_dataset(
        root,
        sensor="hdl64e",
        frames=3,
        layout="semantickitti",
        seed=9,
        progress=False,
        azimuth_bins=256,
    )
    return root


def test_validation_and_test_frames_never_enter_the_cache(target_tree, tmp_path):
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")
    frames = {j.frame for j in list_jobs(cfg) if j.role == "target"}
    assert "sequences/00/velodyne/000002.bin" not in frames and len(frames) == 2


def test_a_split_pattern_that_matches_nothing_is_an_error(target_tree, tmp_path):
    raw = _config(target_tree, tmp_path / "w.pt")
    raw["pairs"]["kitti"]["target"]["split"]["test"] = ["sequences/00/velodyne/999999.bin"]
    with pytest.raises(TrainingError, match="999999"):
        list_jobs(parse_train_config(raw, "test"))


def test_overlapping_splits_and_the_old_holdout_key_are_refused(target_tree, tmp_path):
    raw = _config(target_tree, tmp_path / "w.pt")
    raw["pairs"]["kitti"]["target"]["split"]["test"] = ["sequences/00/velodyne/000001.bin"]
    with pytest.raises(TrainingError, match="both split.train and split.test"):
        list_jobs(parse_train_config(raw, "test"))
    raw = _config(target_tree, tmp_path / "w.pt")
    raw["pairs"]["kitti"]["target"]["holdout"] = ["sequences/00/velodyne/000002.bin"]
    with pytest.raises(ConfigError, match="replaced by 'split'"):
        parse_train_config(raw, "test")


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
    assert model.meta.training["steps"] == summary["selected_step"]
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
    for (name, ta), (_, tb) in zip(
        a.generator.state_dict().items(), b.generator.state_dict().items(), strict=True
    ):
        assert ta.equal(tb), name


def test_a_checkpoint_of_another_config_is_refused(target_tree, tmp_path):
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")
    train(cfg, run_dir=tmp_path / "run", progress=False, max_steps=2)
    changed = dataclasses.replace(cfg, lr=1e-3)
    with pytest.raises(TrainingError, match="another config"):
        train(changed, run_dir=tmp_path / "run", progress=False)


def test_the_weights_are_the_checkpoint_that_scored_best_on_validation(target_tree, tmp_path):
    import json

    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt", steps=6), "test")
    summary = train(cfg, run_dir=tmp_path / "run", progress=False)
    record = json.loads((tmp_path / "run" / "selection.json").read_text())
    assert [h["step"] for h in record["history"]] == [2, 4, 6]
    best = min(record["history"], key=lambda h: h["score"])
    assert summary["selected_step"] == best["step"] == record["best"]["step"]
    assert (tmp_path / "w.pt").read_bytes() == (tmp_path / "run" / "best.pt").read_bytes()
    assert load_model(tmp_path / "w.pt").meta.training["steps"] == best["step"]


def test_evaluation_fits_baselines_on_train_frames_and_scores_only_its_split(
    target_tree, tmp_path, monkeypatch
):
    from lads.intensity import baselines
    from lads.intensity.commands import evaluate_pair

    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")
    train(cfg, run_dir=tmp_path / "run", progress=False)
    seen = {}
    real_fit = baselines.fit_baselines

    def spy(reference, **kwargs):
        frames = list(reference)
        seen["reference"] = [f.name for f in frames]
        return real_fit(frames, **kwargs)

    monkeypatch.setattr(baselines, "fit_baselines", spy)
    result = evaluate_pair(
        cfg,
        cfg.pairs[0],
        str(tmp_path / "w.pt"),
        tmp_path / "ev",
        split="validation",
        figures=False,
    )
    assert seen["reference"] == [
        "sequences/00/velodyne/000000.bin",
        "sequences/00/velodyne/000001.bin",
    ]
    assert result["frames"] == ["sequences/00/velodyne/000002.bin"]
    assert "bound_in_sample" in result["methods"] and "per_class_median" in result["methods"]
    with pytest.raises(TrainingError, match="no test frame"):
        evaluate_pair(cfg, cfg.pairs[0], str(tmp_path / "w.pt"), tmp_path / "ev2")


def test_a_residual_run_stores_the_law_fitted_on_its_training_frames(target_tree, tmp_path):
    from lads.intensity.fitted_physics import FittedPhysics

    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt", residual=True), "test")
    summary = train(cfg, run_dir=tmp_path / "run", progress=False)
    model = load_model(summary["weights"])
    law = FittedPhysics.from_json(model.meta.targets["kitti"].law)
    assert law.intercepts and -3.0 < law.b1 < 3.0
    assert model.meta.training["physics_reference"]["kitti"]["points"] > 1000


def test_pointwise_configs_need_a_residual_law_and_identity_points_need_pointwise(
    target_tree, tmp_path
):
    pointwise = {"residual": True, "architecture": "pointwise", "identity_points": 500}
    ok = parse_train_config(_config(target_tree, tmp_path / "w.pt", **pointwise), "t")
    assert ok.architecture == "pointwise" and ok.identity_points == 500
    for changes, match in (
        ({"architecture": "pointwise"}, "residual: true"),
        ({"architecture": "transformer", "residual": True}, "architecture"),
        ({"identity_points": 500, "residual": True}, "needs architecture: pointwise"),
        ({"lr_decay_from": 1.0}, "lr_decay_from"),
    ):
        with pytest.raises(ConfigError, match=match):
            parse_train_config(_config(target_tree, tmp_path / "w.pt", **changes), "t")


def test_the_learning_rate_decays_linearly_to_zero_from_its_start():
    from lads.intensity.train import learning_rate

    cfg = dataclasses.replace(_parsed_for_lr(), lr=1e-3, steps=100, lr_decay_from=0.5)
    assert learning_rate(cfg, 0) == learning_rate(cfg, 49) == 1e-3
    assert learning_rate(cfg, 75) == pytest.approx(0.5e-3)
    assert learning_rate(cfg, 100) == 0.0
    assert learning_rate(dataclasses.replace(cfg, lr_decay_from=None), 99) == 1e-3


def _parsed_for_lr():
    return parse_train_config(_config(Path("/nonexistent"), Path("w.pt")), "t")


def test_identity_points_are_occupied_pixels_of_the_training_frames(target_tree, tmp_path):
    import numpy as np

    from lads.intensity.sampler import GEN_MASK_INDEX, Sampler

    pointwise = {"residual": True, "architecture": "pointwise", "identity_points": 300}
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt", **pointwise), "t")
    jobs = build_cache(tmp_path / "run", cfg, progress=False)

    def draw_points():
        sampler = Sampler(tmp_path / "run", jobs, np.random.default_rng(1))
        return sampler.points("kitti", 300, (-1.0, 1.0, 0.005))

    draw, again = draw_points(), draw_points()
    assert draw.raw.shape[2:] == (300, 1) and draw.z is not None and draw.z.shape == (1, 1, 300, 1)
    assert bool((draw.raw[0, GEN_MASK_INDEX[draw.raw.shape[1]]] == 1).all())
    assert bool((draw.raw == again.raw).all())  # drawn from the sampler's own rng only


def test_a_pointwise_run_trains_scores_its_law_alone_first_and_loads(target_tree, tmp_path):
    import json

    cfg = parse_train_config(
        _config(
            target_tree,
            tmp_path / "w.pt",
            residual=True,
            architecture="pointwise",
            identity_points=400,
            point_width=8,
            point_layers=1,
            lr_decay_from=0.5,
        ),
        "t",
    )
    summary = train(cfg, run_dir=tmp_path / "run", progress=False)
    record = json.loads((tmp_path / "run" / "selection.json").read_text())
    assert [h["step"] for h in record["history"]] == [0, 2, 4]  # step 0: the law alone
    model = load_model(summary["weights"])
    assert model.meta.architecture == "pointwise" and model.meta.base == 8
    assert type(model.generator).__name__ == "PointGenerator"


def test_materials_with_too_few_training_points_keep_the_zero_vector(target_tree, tmp_path):
    import torch

    from lads.intensity.train_nets import Nets
    from lads.physics.materials import material_names

    pointwise = {"residual": True, "architecture": "pointwise", "identity_points": 300}
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt", **pointwise), "t")
    nets = Nets(cfg, {"kitti": True})
    held = nets.hold_rare_materials({0: 5000, 1: 10}, 100)
    names = material_names()
    assert names[1] in held and names[0] not in held and names[2] in held  # 2: never seen
    table = nets.g.material_embedding.weight
    opt = torch.optim.Adam(nets.g.parameters(), lr=0.1)
    raw = torch.rand(1, len(nets.channels), 6, 1)
    raw[0, nets.channels.index("material"), :, 0] = torch.tensor([1.0, 2.0, 3.0, 1.0, 2.0, 3.0])
    for _ in range(3):
        opt.zero_grad()
        nets.g(raw, torch.ones(1, 1, 6, 1), torch.rand(1, 1, 6, 1)).sub(1).square().sum().backward()
        opt.step()
    assert bool(table[1].abs().sum() > 0)  # material 0, well supported, learns
    assert bool((table[2:] == 0).all()) and bool((table[0] == 0).all())
    assert nets.hold_rare_materials({0: 5000}, 0) == ()


def test_a_run_records_the_materials_it_held_and_rejects_a_negative_minimum(target_tree, tmp_path):
    changes = {
        "residual": True,
        "architecture": "pointwise",
        "identity_points": 300,
        "point_width": 8,
        "point_layers": 1,
        "material_min_points": 10**9,
    }
    cfg = parse_train_config(_config(target_tree, tmp_path / "w.pt", **changes), "t")
    model = load_model(train(cfg, run_dir=tmp_path / "run", progress=False)["weights"])
    assert len(model.meta.training["materials_held"]) == len(model.meta.materials)
    assert bool((model.generator.material_embedding.weight == 0).all())
    assert model.meta.training["config"]["material_min_points"] == 10**9
    # The support counted is every occupied pixel of the labelled target training frames.
    from lads.intensity.cache import iter_frames
    from lads.intensity.features import channel_names
    from lads.intensity.train import _material_points

    jobs = list_jobs(cfg)
    counts = _material_points(tmp_path / "run", jobs)
    names = channel_names(False)
    occupied = [
        f.inputs[names.index("material")][f.inputs[names.index("mask")] > 0]
        for f in iter_frames(tmp_path / "run", jobs)
        if f.role == "target"
    ]
    assert sum(counts.values()) == sum(o.size for o in occupied) > 0
    assert set(counts) == {int(m) - 1 for o in occupied for m in set(o.tolist()) if m > 0}
    for bad in (-1, 2.5, True):
        changes["material_min_points"] = bad
        with pytest.raises(ConfigError, match="material_min_points"):
            parse_train_config(_config(target_tree, tmp_path / "w.pt", **changes), "t")
