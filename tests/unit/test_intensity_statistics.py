"""Training statistics of the intensity model: one streaming pass, exact moments, and a
calibration median within one histogram bin of the exact one."""

from __future__ import annotations

import weakref
from collections.abc import Iterator

import numpy as np
import pytest

from lads.errors import TrainingError
from lads.intensity.cache import CachedFrame
from lads.intensity.cache_statistics import LOG_RATIO_BIN, Statistics, compute_statistics
from lads.intensity.features import NORMALISED_CHANNELS, PHYSICS_FLOOR, channel_names
from lads.intensity.train_config import DomainSpec, PairSpec
from lads.sensors.profile import load_profile

CHANNELS = channel_names(False)
PAIRS = (
    PairSpec("kitti", DomainSpec("synth", frames=1), DomainSpec("synth", frames=1)),
    PairSpec("nusc", DomainSpec("synth", frames=1), DomainSpec("synth", frames=1)),
)
SENSORS = {"kitti": "hdl64e", "nusc": "hdl32e"}


def _frame(rng: np.random.Generator, pair: str, role: str, h: int, w: int) -> CachedFrame:
    """A random frame: ~70 % occupied, ~5 % particles, some reflectivities below the floor;
    source frames of "nusc" carry no intensity."""
    inputs = np.zeros((len(CHANNELS), h, w), np.float32)
    planes = {
        "ln_range": rng.uniform(0.5, 4.8, (h, w)),
        "cos_incidence": rng.uniform(0.0, 1.0, (h, w)),
        "reflectance": rng.uniform(0.0, 1.2, (h, w)),
        "ln_physics": np.log(rng.uniform(0.0, 0.2, (h, w)) + PHYSICS_FLOOR),
        "elevation": rng.uniform(-1.0, 1.0, (h, w)),
        "particle": rng.random((h, w)) < 0.05,
        "mask": rng.random((h, w)) < 0.7,
    }
    for name, plane in planes.items():
        inputs[CHANNELS.index(name)] = plane
    with_target = not (pair == "nusc" and role == "source")
    target = rng.uniform(0.0, 0.99, (h, w)).astype(np.float32) if with_target else None
    return CachedFrame(pair, role, f"{pair}-{role}", inputs, target, True, 0.0, SENSORS[pair])


def _frames(seed: int, n: int, h: int, w: int) -> list[CachedFrame]:
    rng = np.random.default_rng(seed)
    return [
        _frame(rng, pair, role, h, w)
        for _ in range(n)
        for pair in SENSORS
        for role in ("source", "target")
    ]


def _exact(frames: list[CachedFrame]) -> Statistics:
    """The reference: every occupied value of the whole data set concatenated in memory."""
    occ = [f.inputs[CHANNELS.index("mask")] > 0.5 for f in frames]
    values = {
        c: np.concatenate(
            [
                f.inputs[CHANNELS.index(c)][o].astype(np.float64)
                for f, o in zip(frames, occ, strict=True)
            ]
        )
        for c in NORMALISED_CHANNELS
    }
    ratios: dict[str, list[np.ndarray]] = {}
    logs: dict[str, list[np.ndarray]] = {}
    for f, o in zip(frames, occ, strict=True):
        if f.target is None:
            continue
        floor = load_profile(f.sensor).intensity.detection_floor
        refl = f.target[o].astype(np.float64)
        ln_phys = f.inputs[CHANNELS.index("ln_physics")][o].astype(np.float64)
        phys = np.maximum(np.exp(ln_phys) - PHYSICS_FLOOR, 1e-12)
        good = (refl > floor) & ~(f.inputs[CHANNELS.index("particle")][o] > 0.5)
        ratios.setdefault(f.sensor, []).append(np.log(refl[good]) - np.log(phys[good]))
        if f.role == "target":
            logs.setdefault(f.pair, []).append(np.log(refl + floor))
    calibration = {s: float(np.median(np.concatenate(v))) for s, v in ratios.items()}
    targets = {}
    for key, parts in logs.items():
        sensor = SENSORS[key]
        all_logs = np.concatenate(parts)
        targets[key] = {
            "sensor": sensor,
            "log_mean": float(all_logs.mean()),
            "log_std": float(max(all_logs.std(), 1e-3)),
            "floor": load_profile(sensor).intensity.detection_floor,
            "log_k": calibration[sensor],
        }
    mean = {c: float(v.mean()) for c, v in values.items()}
    std = {c: float(v.std()) for c, v in values.items()}
    return Statistics(mean, std, targets, calibration)


def _assert_matches(got: Statistics, want: Statistics) -> None:
    """Moments to 1e-9 relative; medians (calibration, log_k) within one bin width."""
    assert got.mean == pytest.approx(want.mean, rel=1e-9, abs=1e-12)
    assert got.std == pytest.approx(want.std, rel=1e-9, abs=1e-12)
    assert got.calibration.keys() == want.calibration.keys()
    for sensor, exact in want.calibration.items():
        assert abs(got.calibration[sensor] - exact) <= LOG_RATIO_BIN, sensor
    assert got.targets.keys() == want.targets.keys()
    for key, exact in want.targets.items():
        stats = got.targets[key]
        assert stats.keys() == exact.keys()
        assert (stats["sensor"], stats["floor"]) == (exact["sensor"], exact["floor"])
        assert stats["log_mean"] == pytest.approx(exact["log_mean"], rel=1e-9)
        assert stats["log_std"] == pytest.approx(exact["log_std"], rel=1e-9)
        assert abs(stats["log_k"] - exact["log_k"]) <= LOG_RATIO_BIN


@pytest.mark.parametrize(("seed", "n", "h", "w"), [(0, 1, 3, 5), (1, 3, 16, 64), (2, 6, 64, 256)])
def test_streamed_statistics_equal_the_exact_concatenated_ones(seed, n, h, w):
    frames = _frames(seed, n, h, w)
    _assert_matches(compute_statistics(iter(frames), CHANNELS, PAIRS), _exact(frames))


def _with_ratios(ratios: list[float]) -> CachedFrame:
    """A "kitti" target frame whose only measured returns have these ln(refl / I_P)."""
    frame = _frame(np.random.default_rng(5), "kitti", "target", 1, len(ratios))
    inputs = frame.inputs.copy()
    inputs[CHANNELS.index("mask")] = 1.0
    inputs[CHANNELS.index("particle")] = 0.0
    # Keep refl above the detection floor and I_P above its clamp: scale whichever is free.
    r = np.asarray(ratios, np.float64)
    refl, phys = np.where(r > 0, 0.1 * np.exp(r), 0.5), np.where(r > 0, 0.1, 0.5 * np.exp(-r))
    target = refl.astype(np.float32)[None]
    inputs[CHANNELS.index("ln_physics"), 0] = np.log(phys + PHYSICS_FLOOR)
    return CachedFrame("kitti", "target", "k", inputs, target, True, 0.0, "hdl64e")


@pytest.mark.parametrize(
    "ratios",
    [
        [0.0, 5.0],
        [0.1, 0.2, 0.3, 9.0],
        [0.3, 0.2, 60.0],
        [-50.0, 0.1, 0.2],
        [-12.0, 0.0, 0.0, 0.0, 2e-5],
    ],
)
def test_the_median_is_within_one_bin_for_gaps_ties_and_values_beyond_the_range(ratios):
    # An even count takes the midpoint of two far-apart middle values (as np.median), and a
    # ratio beyond the histogram range still counts towards the median's rank.
    frames = [_with_ratios(ratios)]
    got = compute_statistics(frames, CHANNELS, PAIRS[:1]).calibration["hdl64e"]
    assert abs(got - _exact(frames).calibration["hdl64e"]) <= LOG_RATIO_BIN


class _OnceOnly:
    """Frames made on demand that may be iterated once only, counting how many earlier
    frames are still alive when each new one is made."""

    def __init__(self, seed: int, n: int) -> None:
        self.seed, self.n = seed, n
        self.iterated = False
        self.most_alive = 0

    def __iter__(self) -> Iterator[CachedFrame]:
        if self.iterated:
            raise RuntimeError("the frame stream was iterated twice")
        self.iterated = True
        rng = np.random.default_rng(self.seed)
        made: list[weakref.ref] = []
        for i in range(self.n):
            alive = sum(ref() is not None for ref in made)
            self.most_alive = max(self.most_alive, alive)
            pair = ("kitti", "nusc")[i % 2]
            frame = _frame(rng, pair, ("source", "target")[(i // 2) % 2], 8, 32)
            made.append(weakref.ref(frame.inputs))
            yield frame
            del frame


def test_the_frames_are_consumed_once_and_never_held_together():
    stream = _OnceOnly(seed=3, n=12)
    got = compute_statistics(stream, CHANNELS, PAIRS)
    assert stream.iterated
    # At most the previous frame (still bound while the next one is read) is alive.
    assert stream.most_alive <= 1
    _assert_matches(got, _exact(list(_OnceOnly(seed=3, n=12))))


def test_a_pair_without_target_frames_is_still_a_training_error():
    frames = (f for f in _frames(4, 2, 4, 8) if not (f.pair == "nusc" and f.role == "target"))
    with pytest.raises(
        TrainingError,
        match=r"^pair nusc: no target frame with an intensity "
        r"in the cache\.$",
    ):
        compute_statistics(frames, CHANNELS, PAIRS)


def test_target_frames_without_an_intensity_do_not_count_as_target_data():
    frames = [
        CachedFrame(
            f.pair, f.role, f.frame, f.inputs, None, f.labelled, f.extinction_per_m, f.sensor
        )
        if f.pair == "nusc"
        else f
        for f in _frames(6, 1, 4, 8)
    ]
    with pytest.raises(TrainingError, match="pair nusc: no target frame with an intensity"):
        compute_statistics(iter(frames), CHANNELS, PAIRS)
