"""One streaming pass over a run's cache: normalisation statistics and per-pair facts, stored
in `runs/<name>/statistics.json` and reused while the cache is unchanged (a full dataset
takes minutes to re-read)."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from lads.errors import LadsError, TrainingError
from lads.files import atomic_write
from lads.intensity.cache import CachedFrame, CacheJob, cache_fingerprint, iter_frames
from lads.intensity.cache_statistics import (
    STATISTICS_VERSION,
    Statistics,
    compute_statistics,
    number_from_json,
    number_to_json,
    statistics_from_json,
    statistics_to_json,
)
from lads.intensity.features import FEATURE_VERSION, NORMALISED_CHANNELS
from lads.intensity.train_config import PairSpec, TrainConfig
from lads.sensors.profile import load_profile

STATISTICS = "statistics.json"
STATISTICS_FORMAT = "lads-train-statistics"


class PairFacts:
    """Per-pair facts gathered while a pass streams the cache, in O(pairs) memory.

    Attributes:
        labelled: per pair key, whether every target frame carries labels (True without
            target frames, as `all` of nothing).
    """

    def __init__(self, pairs: tuple[PairSpec, ...]) -> None:
        self.labelled = {p.key: True for p in pairs}
        self._alpha_sum = {p.key: 0.0 for p in pairs}
        self._alpha_count = {p.key: 0 for p in pairs}

    def observe(self, frames: Iterable[CachedFrame]) -> Iterator[CachedFrame]:
        """Pass `frames` through unchanged, noting each one's pair facts on the way."""
        for f in frames:
            if f.pair in self.labelled and f.role == "target":
                self.labelled[f.pair] &= f.labelled
            elif f.pair in self.labelled and f.role == "source":
                self._alpha_sum[f.pair] += f.extinction_per_m
                self._alpha_count[f.pair] += 1
            yield f

    def mean_alpha(self) -> dict[str, float]:
        """Per pair key, mean extinction of its source frames (1/m); NaN without any."""
        return {
            k: s / n if (n := self._alpha_count[k]) else float("nan")
            for k, s in self._alpha_sum.items()
        }


@dataclass(frozen=True, slots=True)
class RunStatistics:
    """What training takes from one pass over the whole cache.

    Attributes:
        stats: normalisation and decoding statistics (`compute_statistics`).
        labelled: per pair key, whether every target frame carries labels.
        mean_alpha: per pair key, mean extinction of its source frames, 1/m (NaN without).
    """

    stats: Statistics
    labelled: dict[str, bool]
    mean_alpha: dict[str, float]

    def to_json(self) -> dict[str, Any]:
        """Strict-JSON data that `from_json` reads back exactly (NaN included)."""
        alpha = {k: number_to_json(v) for k, v in self.mean_alpha.items()}
        return {
            "statistics": statistics_to_json(self.stats),
            "labelled": self.labelled,
            "mean_alpha": alpha,
        }

    @classmethod
    def from_json(cls, raw: Any, where: str, pairs: tuple[PairSpec, ...]) -> RunStatistics:
        """Read back `to_json` data made for `pairs`.

        Raises:
            TrainingError: `raw` (from `where`) is not such data.
        """
        keys = [p.key for p in pairs]
        try:
            labelled, alpha = raw["labelled"], raw["mean_alpha"]
            if list(labelled) != keys or list(alpha) != keys:
                raise ValueError(f"pairs {list(labelled)}, {list(alpha)}; expected {keys}")
            if not all(isinstance(v, bool) for v in labelled.values()):
                raise ValueError(f"labelled flags {labelled} are not all true/false")
            mean_alpha = {k: number_from_json(v) for k, v in alpha.items()}
            stats = statistics_from_json(raw["statistics"], where)
        except (KeyError, TypeError, AttributeError, ValueError) as exc:
            raise TrainingError(
                f"{where}: not a statistics record as lads writes it ({type(exc).__name__}: "
                f"{exc}); delete it and it is recomputed from the cache."
            ) from None
        if list(stats.targets) != keys:
            raise TrainingError(
                f"{where}: statistics of pairs {list(stats.targets)}, "
                f"expected {keys}; delete it to recompute."
            )
        return cls(stats, dict(labelled), mean_alpha)


def run_statistics(
    run: Path, cfg: TrainConfig, jobs: list[CacheJob], channels: tuple[str, ...]
) -> RunStatistics:
    """The statistics of the run's cache: read from `run/statistics.json` when that file
    was made from this very cache, else computed in one streaming pass (one frame in memory
    at a time) and stored there for the next start.

    A stored file that is missing, unreadable, damaged, or made for other cached frames, a
    feature definition or statistics code of another version, or other sensor floors, is
    recomputed and overwritten: the values are identical either way, only the minutes spent
    re-reading a full dataset on every resume are saved.

    Raises:
        TrainingError: a cached frame vanished, or a pair has no target intensities.
    """
    path = run / STATISTICS
    key = statistics_key(run, cfg, jobs, channels)
    stored = _stored_statistics(path, key, cfg.pairs)
    if stored is not None:
        return stored
    facts = PairFacts(cfg.pairs)
    stats = compute_statistics(facts.observe(iter_frames(run, jobs)), channels, cfg.pairs)
    found = RunStatistics(stats, facts.labelled, facts.mean_alpha())
    content = found.to_json()
    document = {
        "format": STATISTICS_FORMAT,
        "key": key,
        "floors": _floors(stats),
        "content_sha256": _content_digest(content),
        "content": content,
        # For people reading the file; the key already covers all of it.
        "made_from": {
            "frames": len(jobs),
            "data_hash": cfg.data_hash(),
            "feature_version": FEATURE_VERSION,
            "statistics_version": STATISTICS_VERSION,
        },
    }
    atomic_write(path, json.dumps(document, indent=1, allow_nan=False).encode())
    return found


def statistics_key(
    run: Path, cfg: TrainConfig, jobs: list[CacheJob], channels: tuple[str, ...]
) -> str:
    """sha256 hex digest of everything the statistics of a run depend on: the cached frames
    in streaming order (`cache_fingerprint`), the feature definition and channels, the
    statistics code version, and the pairs (whose keys and domains decide the cache)."""
    payload = {
        "frames": cache_fingerprint(run, jobs),
        "feature_version": FEATURE_VERSION,
        "statistics_version": STATISTICS_VERSION,
        "channels": list(channels),
        "normalised": list(NORMALISED_CHANNELS),
        "kind": cfg.kind,
        "data_hash": cfg.data_hash(),
        "pairs": [asdict(p) for p in cfg.pairs],
    }
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _stored_statistics(path: Path, key: str, pairs: tuple[PairSpec, ...]) -> RunStatistics | None:
    """The statistics stored at `path` if they are intact and made under `key` with the
    sensor floors of today's profiles; None otherwise (including no file)."""
    try:
        document = json.loads(path.read_bytes())
    except (OSError, ValueError):  # absent, unreadable, not UTF-8 or not JSON
        return None
    if not isinstance(document, dict) or document.get("format") != STATISTICS_FORMAT:
        return None
    if document.get("key") != key or "content" not in document:
        return None
    # A flipped digit still parses: only the digest tells a damaged value from a real one.
    if document.get("content_sha256") != _content_digest(document["content"]):
        return None
    try:
        found = RunStatistics.from_json(document["content"], str(path), pairs)
        # compute_statistics reads each sensor's detection floor from its profile, outside
        # the cache: an edited profile makes the stored statistics stale.
        floors = _floors(found.stats)
    except LadsError:
        return None
    return found if document.get("floors") == floors else None


def _floors(stats: Statistics) -> dict[str, float | str]:
    """Detection floor (reflectivity units) of every sensor the statistics saw, as JSON.
    Raises SensorProfileError for a sensor without a profile."""
    return {s: number_to_json(load_profile(s).intensity.detection_floor) for s in stats.calibration}


def _content_digest(content: Any) -> str:
    """sha256 of canonical JSON of `content`: json floats round-trip through their repr,
    so the digest of what was written equals the digest of what is read back."""
    text = json.dumps(content, sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()
