"""Statistics of a run's cache in one streaming pass: normalisation moments of the input
channels, each target's log-intensity statistics and the per-sensor calibration ln k, with
their exact JSON round trip (NaN and inf included)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import TrainingError
from lads.intensity.cache import CachedFrame
from lads.intensity.features import NORMALISED_CHANNELS, PHYSICS_FLOOR
from lads.intensity.train_config import PairSpec
from lads.sensors.profile import load_profile


@dataclass(frozen=True, slots=True)
class Statistics:
    """Normalisation and decoding statistics of a run.

    Attributes:
        mean, std: per raw input channel over occupied pixels of every cached frame.
        targets: per pair key: {"sensor", "log_mean", "log_std", "floor", "log_k"}.
        calibration: ln k per sensor (from every frame with a measured intensity): the
            median of ln(refl / I_P), within LOG_RATIO_BIN = 1e-4 of the exact one.
    """

    mean: dict[str, float]
    std: dict[str, float]
    targets: dict[str, dict[str, Any]]
    calibration: dict[str, float]


# Bump whenever compute_statistics returns anything else for the same frames, so that
# statistics stored by an older lads are recomputed instead of reused.
STATISTICS_VERSION = 1
# JSON has no literal for these; they are stored as the strings Python spells them with.
_NON_FINITE = ("nan", "inf", "-inf")
_TARGET_NUMBERS = ("log_mean", "log_std", "floor", "log_k")


def number_to_json(value: float) -> float | str:
    """A float (or int) as strict-JSON data that `number_from_json` reads back exactly:
    finite values as themselves (json writes floats with repr, the shortest string that
    round-trips; ints stay ints), NaN and infinities as "nan", "inf", "-inf"."""
    return value if math.isfinite(value) else str(float(value))


def number_from_json(raw: Any) -> float:
    """Inverse of `number_to_json`. Raises ValueError for anything it does not write."""
    if isinstance(raw, str) and raw in _NON_FINITE:
        return float(raw)
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        raise ValueError(f"expected a number, got {raw!r}")
    return raw


def _numbers_from_json(raw: Any) -> dict[str, float]:
    if not isinstance(raw, dict):
        raise ValueError(f"expected a mapping of numbers, got {type(raw).__name__}")
    return {str(k): number_from_json(v) for k, v in raw.items()}


def statistics_to_json(stats: Statistics) -> dict[str, Any]:
    """`stats` as strict-JSON data (see `number_to_json`); key order is kept."""

    def numbers(values: dict[str, float]) -> dict[str, float | str]:
        return {k: number_to_json(v) for k, v in values.items()}

    targets = {
        key: {"sensor": t["sensor"], **{n: number_to_json(t[n]) for n in _TARGET_NUMBERS}}
        for key, t in stats.targets.items()
    }
    return {
        "mean": numbers(stats.mean),
        "std": numbers(stats.std),
        "targets": targets,
        "calibration": numbers(stats.calibration),
    }


def statistics_from_json(raw: Any, where: str) -> Statistics:
    """Read back what `statistics_to_json` wrote, value for value.

    Raises:
        TrainingError: `raw` (from `where`) has another layout, a non-number where a
            number belongs, or not exactly the NORMALISED_CHANNELS.
    """
    try:
        mean, std = _numbers_from_json(raw["mean"]), _numbers_from_json(raw["std"])
        if set(mean) != set(NORMALISED_CHANNELS) or set(std) != set(NORMALISED_CHANNELS):
            raise ValueError(f"channels {sorted(mean)}, expected {sorted(NORMALISED_CHANNELS)}")
        targets = {}
        for key, t in raw["targets"].items():
            if not isinstance(t["sensor"], str):
                raise ValueError(f"target {key}: sensor {t['sensor']!r} is not a name")
            numbers = {n: number_from_json(t[n]) for n in _TARGET_NUMBERS}
            targets[str(key)] = {"sensor": t["sensor"], **numbers}
        calibration = _numbers_from_json(raw["calibration"])
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        raise TrainingError(
            f"{where}: not a statistics record as lads writes it ({type(exc).__name__}: "
            f"{exc}); delete it and it is recomputed from the cache."
        ) from None
    return Statistics(mean, std, targets, calibration)


# The calibration median of ln(refl / I_P) is estimated from a fixed histogram instead of
# every value: a 23k-frame SemanticKITTI cache holds ~2e9 measured returns (16 GB as
# float64), while this grid is 800k int64 counts (6.4 MB) per sensor whatever the data size.
# Bins 1e-4 wide are far finer than anything ln k is used for (k to 0.01 %). The range
# covers every physical ratio: reflectivity up to 65535 (ln 11.1) over I_P down to its
# 1e-12 clamp (ln -27.6) gives |ln ratio| < 39; values beyond are clipped into the end
# bins, where they still count towards the median's rank.
LOG_RATIO_RANGE = (-40.0, 40.0)
LOG_RATIO_BIN = 1e-4


@dataclass(slots=True)
class _Moments:
    """Running count, mean and M2 (sum of squared deviations) of float64 samples.

    Frames are merged with Chan et al.'s parallel formula: exact to rounding, and unlike a
    running sum of squares it does not cancel when the spread is small against the mean
    (ln_range ~ 3 +- 0.5 over 1e9 pixels).
    """

    n: int = 0
    mean: float = 0.0
    m2: float = 0.0

    def add(self, values: npt.NDArray[np.floating[Any]]) -> None:
        """Merge a batch of samples (any shape, any float dtype; summed in float64)."""
        n_b = int(values.size)
        if n_b == 0:
            return
        batch = values.astype(np.float64, copy=False).ravel()
        mean_b = float(batch.mean())
        m2_b = float(np.square(batch - mean_b).sum())
        n = self.n + n_b
        delta = mean_b - self.mean
        self.mean += delta * n_b / n
        self.m2 += m2_b + delta * delta * self.n * n_b / n
        self.n = n

    def mean_value(self) -> float:
        """The mean; NaN without samples (as np.mean of nothing, minus its warning)."""
        return self.mean if self.n else float("nan")

    def std_value(self) -> float:
        """The population standard deviation (ddof=0, as np.std); NaN without samples."""
        return float(np.sqrt(self.m2 / self.n)) if self.n else float("nan")


class _MedianHistogram:
    """Bounded-memory median of float64 samples on the fixed LOG_RATIO grid.

    Counts samples in LOG_RATIO_BIN-wide bins over LOG_RATIO_RANGE (values outside are
    clipped into the end bins, still counted); the median is read back with linear
    interpolation inside its bin, so it is within one bin width of np.median's for samples
    inside the range. Memory: one (800000,) int64 array (6.4 MB), independent of the sample
    count.
    """

    def __init__(self) -> None:
        low, high = LOG_RATIO_RANGE
        self.n_bins = int(round((high - low) / LOG_RATIO_BIN))
        self.counts = np.zeros(self.n_bins, dtype=np.int64)
        self.has_nan = False

    def add(self, values: npt.NDArray[np.floating[Any]]) -> None:
        """Count a batch of samples (any shape)."""
        batch = values.astype(np.float64, copy=False).ravel()
        nan = np.isnan(batch)
        if nan.any():
            # np.median of data holding a NaN is NaN; keep that, and keep NaN off the grid.
            self.has_nan = True
            batch = batch[~nan]
        index = np.floor((batch - LOG_RATIO_RANGE[0]) / LOG_RATIO_BIN)
        index = np.clip(index, 0, self.n_bins - 1).astype(np.intp)
        self.counts += np.bincount(index, minlength=self.n_bins)

    def median(self) -> float:
        """The median (mean of the two middle ranks for an even count, as np.median); NaN
        without samples or when any sample was NaN."""
        total = int(self.counts.sum())
        if self.has_nan or total == 0:
            return float("nan")
        cumulative = np.cumsum(self.counts)
        low_rank, high_rank = (total - 1) // 2, total // 2
        return 0.5 * (
            self._rank_value(cumulative, low_rank) + self._rank_value(cumulative, high_rank)
        )

    def _rank_value(self, cumulative: npt.NDArray[np.int64], rank: int) -> float:
        """Value of the 0-based `rank`-th sample, its bin's samples taken as evenly spread
        over the bin (so within one bin width of the true value)."""
        i = int(np.searchsorted(cumulative, rank, side="right"))
        before = int(cumulative[i - 1]) if i else 0
        fraction = (rank - before + 0.5) / int(self.counts[i])
        return LOG_RATIO_RANGE[0] + (i + fraction) * LOG_RATIO_BIN


@dataclass(slots=True)
class _TargetTally:
    """Running statistics of one pair's target frames: ln(refl + floor) moments, the
    number of target frames with an intensity, and the floor and sensor of the last one."""

    logs: _Moments = field(default_factory=_Moments)
    frames: int = 0
    floor: float = 0.0
    sensor: str = ""


def _frame_logs(
    f: CachedFrame, channels: tuple[str, ...], occ: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]:
    """One frame's ln(refl + floor) over occupied pixels (K,), its calibration log ratios
    ln(refl / I_P) over surface returns with a measured signal (<= K,), and the floor.
    Both float64; `f.target` must not be None."""
    floor = load_profile(f.sensor).intensity.detection_floor
    refl = f.target[occ].astype(np.float64)  # type: ignore[index]
    ln_refl = np.log(refl + floor)
    ln_phys = f.inputs[channels.index("ln_physics")][occ].astype(np.float64)
    phys = np.maximum(np.exp(ln_phys) - PHYSICS_FLOOR, 1e-12)
    # Calibration from surface returns with a measured signal only.
    particle = f.inputs[channels.index("particle")][occ] > 0.5
    good = (refl > floor) & ~particle
    return ln_refl, np.log(refl[good]) - np.log(phys[good]), floor


def compute_statistics(
    frames: Iterable[CachedFrame], channels: tuple[str, ...], pairs: tuple[PairSpec, ...]
) -> Statistics:
    """Statistics over occupied pixels only, in one streaming pass.

    Args:
        frames: every cached frame, any iterable (e.g. `iter_frames`); consumed once, one
            frame held at a time, so memory does not grow with the number of frames.
        channels: names of the (C,) input planes of each frame's `inputs` (C, H, W).
        pairs: the run's pairs; each needs a target frame with an intensity.

    Means and standard deviations (ddof=0) are exact to float64 rounding. The calibration
    ln k (median of ln(refl / I_P) per sensor) comes from a fixed histogram of
    LOG_RATIO_BIN = 1e-4 wide bins over LOG_RATIO_RANGE = [-40, 40] (ln units), read with
    linear interpolation inside the median bin: within 1e-4 of the exact median (values
    outside the range are clipped into the end bins). Empty data give NaN statistics.

    Raises:
        TrainingError: a pair without a target frame with an intensity.
    """
    mask_i = channels.index("mask")
    inputs = {c: _Moments() for c in NORMALISED_CHANNELS}
    log_ratio: dict[str, _MedianHistogram] = {}
    tallies = {p.key: _TargetTally() for p in pairs}
    for f in frames:
        occ = f.inputs[mask_i] > 0.5
        for c in NORMALISED_CHANNELS:
            inputs[c].add(f.inputs[channels.index(c)][occ])
        if f.target is None:
            continue
        ln_refl, ratio, floor = _frame_logs(f, channels, occ)
        log_ratio.setdefault(f.sensor, _MedianHistogram()).add(ratio)
        if f.role == "target":
            tally = tallies[f.pair]
            tally.logs.add(ln_refl)
            tally.frames += 1
            tally.floor, tally.sensor = floor, f.sensor
    mean = {c: m.mean_value() for c, m in inputs.items()}
    std = {c: m.std_value() for c, m in inputs.items()}
    calibration = {s: h.median() for s, h in log_ratio.items()}
    return Statistics(mean, std, _target_statistics(tallies, calibration), calibration)


def _target_statistics(
    tallies: dict[str, _TargetTally], calibration: dict[str, float]
) -> dict[str, dict[str, Any]]:
    """Per pair {"sensor", "log_mean", "log_std", "floor", "log_k"}. Raises TrainingError."""
    targets = {}
    for key, tally in tallies.items():
        if not tally.frames:
            raise TrainingError(f"pair {key}: no target frame with an intensity in the cache.")
        targets[key] = {
            "sensor": tally.sensor,
            "log_mean": tally.logs.mean_value(),
            "log_std": float(max(tally.logs.std_value(), 1e-3)),
            "floor": tally.floor,
            "log_k": calibration.get(tally.sensor, 0.0),
        }
    return targets
