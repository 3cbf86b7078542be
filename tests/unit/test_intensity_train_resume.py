"""Restarting `lads train`: the statistics pass runs once per cache, and the sampler's frame
cache keeps what is drawn often without changing what is drawn."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from lads.intensity import run_statistics as stats_module
from lads.intensity import sampler as sampler_module
from lads.intensity.cache import build_cache, iter_frames
from lads.intensity.cache_statistics import Statistics, compute_statistics
from lads.intensity.features import NORMALISED_CHANNELS, channel_names
from lads.intensity.run_statistics import STATISTICS, PairFacts, RunStatistics
from lads.intensity.sampler import Sampler
from lads.intensity.train import train
from lads.intensity.train_config import DomainSpec, PairSpec, parse_train_config
from tests.unit import test_intensity_training as training

_config = training._config
target_tree = training.target_tree  # the tiny SemanticKITTI-like tree of the training tests
CHANNELS = channel_names(False)


class StatisticsPasses:
    """Stands in for `compute_statistics` in the train module and counts its calls."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, *args, **kwargs) -> Statistics:
        self.calls += 1
        return compute_statistics(*args, **kwargs)


@pytest.fixture
def passes(monkeypatch) -> StatisticsPasses:
    counter = StatisticsPasses()
    monkeypatch.setattr(stats_module, "compute_statistics", counter)
    return counter


@pytest.fixture
def tiny(target_tree, tmp_path):
    """The tiny sensor config of the training tests, writing its weights under tmp_path."""
    return parse_train_config(_config(target_tree, tmp_path / "w.pt"), "test")


def _start(cfg, run: Path) -> None:
    """A start that stops before the first step: cache, statistics, networks, resume."""
    train(cfg, run_dir=run, progress=False, max_steps=0)


def _as_text(facts: RunStatistics) -> str:
    """Exact, NaN-aware comparison form (NaN != NaN would defeat ==)."""
    return json.dumps(facts.to_json(), sort_keys=True)


def test_a_second_start_reuses_the_stored_statistics(tiny, tmp_path, passes):
    run = tmp_path / "run"
    _start(tiny, run)
    assert passes.calls == 1 and (run / STATISTICS).is_file()
    _start(tiny, run)
    jobs = build_cache(run, tiny, progress=False)
    stored = stats_module.run_statistics(run, tiny, jobs, CHANNELS)
    assert passes.calls == 1  # neither the second start nor run_statistics re-read the cache
    fresh = PairFacts(tiny.pairs)
    stats = compute_statistics(fresh.observe(iter_frames(run, jobs)), CHANNELS, tiny.pairs)
    assert _as_text(stored) == _as_text(RunStatistics(stats, fresh.labelled, fresh.mean_alpha()))


def test_weights_are_the_same_bytes_with_stored_or_computed_statistics(tiny, tmp_path, monkeypatch):
    train(tiny, run_dir=tmp_path / "computed", progress=False)
    computed = (tmp_path / "w.pt").read_bytes()
    (tmp_path / "w.pt").unlink()
    _start(tiny, tmp_path / "stored")

    def no_pass(*args, **kwargs):
        raise AssertionError("the statistics pass ran although they were stored")

    monkeypatch.setattr(stats_module, "compute_statistics", no_pass)
    train(tiny, run_dir=tmp_path / "stored", progress=False)
    assert (tmp_path / "w.pt").read_bytes() == computed


def _more_source_frames(raw: dict) -> None:
    raw["pairs"]["kitti"]["source"]["frames"] = 3


def _other_range_exponent(raw: dict) -> None:
    raw["range_exponent"] = 2.0


def _no_split(raw: dict) -> None:
    raw["pairs"]["kitti"]["target"]["split"] = {}


@pytest.mark.parametrize("change", [_more_source_frames, _other_range_exponent, _no_split])
def test_another_cache_recomputes_the_statistics(target_tree, tmp_path, passes, change):
    raw = _config(target_tree, tmp_path / "w.pt")
    run = tmp_path / "run"
    _start(parse_train_config(raw, "test"), run)
    change(raw)
    changed = parse_train_config(raw, "test")
    _start(changed, run)
    assert passes.calls == 2
    _start(changed, run)  # and the recomputed file is what later starts reuse
    assert passes.calls == 2


def test_a_rebuilt_cache_frame_recomputes_the_statistics(tiny, tmp_path, passes):
    run = tmp_path / "run"
    _start(tiny, run)
    # Same job, same key: only the frame's rewrite tells that its content may differ.
    job = build_cache(run, tiny, progress=False)[0]
    victim = run / "cache.zarr" / job.node / "zarr.json"
    victim.write_text(victim.read_text().replace('"done": true', '"done": false'))
    _start(tiny, run)
    assert passes.calls == 2


def test_a_new_feature_version_recomputes_the_statistics(tiny, tmp_path, passes, monkeypatch):
    _start(tiny, tmp_path / "run")
    monkeypatch.setattr(stats_module, "FEATURE_VERSION", stats_module.FEATURE_VERSION + "-next")
    _start(tiny, tmp_path / "run")
    assert passes.calls == 2


def test_an_edited_sensor_floor_recomputes_the_statistics(tiny, tmp_path, passes, monkeypatch):
    _start(tiny, tmp_path / "run")

    def floors(stats):
        return {sensor: 0.125 for sensor in stats.calibration}

    monkeypatch.setattr(stats_module, "_floors", floors)
    _start(tiny, tmp_path / "run")
    assert passes.calls == 2


def _truncate(text: str) -> str:
    return text[: len(text) // 2]


def _edit(text: str, change, *, redigest: bool) -> str:
    """`text` with `change` applied to its content; `redigest` also updates the content
    digest, as a hand edit that knows the format would."""
    document = json.loads(text)
    change(document["content"])
    if redigest:
        document["content_sha256"] = stats_module._content_digest(document["content"])
    return json.dumps(document)


def _changed_value(text: str) -> str:
    def nudge(content):
        content["statistics"]["mean"]["ln_range"] += 1e-9

    return _edit(text, nudge, redigest=False)


def _wrong_type(text: str) -> str:
    def spoil(content):
        content["labelled"]["kitti"] = "yes"

    return _edit(text, spoil, redigest=True)


def _missing_channel(text: str) -> str:
    def drop(content):
        del content["statistics"]["std"]["ln_range"]

    return _edit(text, drop, redigest=True)


DAMAGES = {
    "empty": lambda text: "",
    "truncated": _truncate,
    "not-utf8": lambda text: "\udcff{",
    "not-a-record": lambda text: "[]",
    "changed-value": _changed_value,
    "wrong-type": _wrong_type,
    "missing-channel": _missing_channel,
}


@pytest.mark.parametrize("damage", DAMAGES.values(), ids=DAMAGES.keys())
def test_a_damaged_statistics_file_is_recomputed_and_rewritten(tiny, tmp_path, passes, damage):
    run = tmp_path / "run"
    _start(tiny, run)
    good = (run / STATISTICS).read_text()
    damaged = damage(good)
    assert damaged != good
    (run / STATISTICS).write_bytes(damaged.encode("utf-8", "surrogateescape"))
    _start(tiny, run)
    assert passes.calls == 2
    assert (run / STATISTICS).read_text() == good
    _start(tiny, run)
    assert passes.calls == 2


def test_stored_statistics_round_trip_exactly_with_nan_infinities_and_ints():
    pairs = (PairSpec("snow", DomainSpec("synth", frames=1), DomainSpec("synth", frames=1)),)
    mean = {c: 0.1 + i / 3 for i, c in enumerate(NORMALISED_CHANNELS)}
    std = {c: float("nan") if i == 0 else 5e-324 for i, c in enumerate(NORMALISED_CHANNELS)}
    targets = {
        "snow": {
            "sensor": "hdl64e",
            "log_mean": -1 / 7,
            "log_std": float("inf"),
            "floor": 0,
            "log_k": -float("inf"),
        }
    }
    facts = RunStatistics(
        Statistics(mean, std, targets, {"hdl64e": 1e300}), {"snow": False}, {"snow": float("nan")}
    )
    text = json.dumps(facts.to_json(), allow_nan=False)  # strict JSON: no NaN literal
    back = RunStatistics.from_json(json.loads(text), "test", pairs)
    assert _as_text(back) == _as_text(facts)
    assert math.isnan(back.mean_alpha["snow"]) and math.isnan(back.stats.std["ln_range"])
    assert type(back.stats.targets["snow"]["floor"]) is int  # ints stay ints
    assert back.stats.mean == mean


# --- The sampler's frame cache ---------------------------------------------------------


def _jobs(n: int) -> list[stats_module.CacheJob]:
    domain = DomainSpec("synth", frames=n)
    return [
        stats_module.CacheJob("p", "source", domain, f"synth-{i:06d}", "sensor", 1.0)
        for i in range(n)
    ]


def test_the_sampler_keeps_a_frequently_drawn_frame_and_drops_a_cold_one(tmp_path, monkeypatch):
    reads: list[str] = []

    def read_frame(run_dir, job):
        reads.append(job.frame)
        return job.frame  # which frames are held is under test, not what they hold

    monkeypatch.setattr(sampler_module, "read_frame", read_frame)
    monkeypatch.setattr(sampler_module, "FRAME_CACHE", 2)
    hot, cold, new = _jobs(3)
    sampler = Sampler(tmp_path, [hot, cold, new], np.random.default_rng(0))
    for job in (hot, cold, hot, new, hot):
        sampler.frame(job)
    # Evicting the oldest inserted would have dropped `hot` for `new` and read it again.
    assert reads == [hot.frame, cold.frame, new.frame]
    sampler.frame(cold)
    assert reads[-1] == cold.frame  # the cold frame was the one dropped


def test_eviction_never_changes_the_batches(tiny, tmp_path, monkeypatch):
    jobs = build_cache(tmp_path, tiny, progress=False)

    def batches(frame_cache: int) -> list[torch.Tensor]:
        monkeypatch.setattr(sampler_module, "FRAME_CACHE", frame_cache)
        sampler = Sampler(tmp_path, jobs, np.random.default_rng(5))
        out = []
        for _ in range(6):
            for role in ("source", "target"):
                b = sampler.batch("kitti", role, 3, 16, (0.0, 1.0, 0.01))
                out += [b.raw, b.mask, b.extinction] + ([] if b.z is None else [b.z])
        return out

    for held_one, held_all in zip(batches(1), batches(64), strict=True):
        assert held_one.equal(held_all)


def test_a_run_started_afresh_does_not_inherit_an_earlier_runs_choice(tiny, tmp_path):
    """A best checkpoint left in the run folder by an earlier run (its checkpoint deleted,
    or another config) must not be chosen over the new run's own checkpoints."""
    run = tmp_path / "run"
    train(tiny, run_dir=run, progress=False)
    planted = json.loads((run / "selection.json").read_text())
    planted["best"]["score"] = -1.0  # better than anything a real run can score
    (run / "selection.json").write_text(json.dumps(planted))
    (run / "checkpoints" / "latest.pt").unlink()
    train(tiny, run_dir=run, progress=False)
    record = json.loads((run / "selection.json").read_text())
    assert record["best"]["score"] >= 0.0
    assert [h["step"] for h in record["history"]] == sorted({h["step"] for h in record["history"]})
