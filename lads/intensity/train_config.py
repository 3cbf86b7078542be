"""Training configs for the intensity models (`pipelines/train/*.yaml`).

A config names the model, its kind, and one or more *pairs*: an unpaired source domain
(simulation) and a target domain (real recordings) under one key. Sensor models have one
pair keyed by the target's name; weather models have one pair per weather style ("snow",
"fog"), all feeding one style-conditioned generator. Unknown keys are errors.

Relative paths are taken from the repository root (the folder holding `pipelines/`), so
`../shared/data/...` works from any working directory.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from lads.config import PIPELINE_DIR
from lads.errors import ConfigError
from lads.intensity.features import STYLES

REPO_ROOT = PIPELINE_DIR.parent
TRAIN_DIR = PIPELINE_DIR / "train"
KINDS = ("sensor", "weather")


@dataclass(frozen=True, slots=True)
class DomainSpec:
    """Where one domain's frames come from.

    Attributes:
        dataset: a reader name (`lads.readers.READERS`) or "synth" (made here, in memory).
        root: dataset root (None for synth).
        sensor: sensor profile of the frames (default: the reader's).
        frames: synth only: number of frames; readers: at most this many (0 = all).
        seed: synth street seed; also seeds the weather stage for weather sources.
        holdout: relative paths (as the reader names items) never used for training.
        weather: for weather sources: the physics stage applied first, e.g.
            {"stage": "snow", "rate_mm_h": 2.5}.
        extinction_per_m: alpha assumed for target recordings in weather (1/m), used in
            their I_P; sources in weather take alpha from the physics stage.
        azimuth_bins: synth only: beams per ring (default the profile's width).
    """

    dataset: str
    root: str | None = None
    sensor: str | None = None
    frames: int = 0
    seed: int = 0
    holdout: tuple[str, ...] = ()
    weather: dict[str, Any] = field(default_factory=dict)
    extinction_per_m: float = 0.0
    azimuth_bins: int | None = None

    def root_path(self) -> Path | None:
        if self.root is None:
            return None
        p = Path(self.root).expanduser()
        return p if p.is_absolute() else (REPO_ROOT / p).resolve()


@dataclass(frozen=True, slots=True)
class PairSpec:
    key: str
    source: DomainSpec
    target: DomainSpec


@dataclass(frozen=True, slots=True)
class LossWeights:
    """Weights of the generator objective (paper: L_adv + l_cyc L_cyc + l_phy L_phy).

    identity: CycleGAN's identity term, here G(target's own physics inputs) ~ target
        intensity, used only when the target frames carry labels (else 0 in effect).
    style: multi-style consistency (weather models).
    identity_balance: power of the inverse material frequency that weights the identity
        term's pixels (0: plain mean; 0.5: a material with 100x fewer pixels counts 10x
        more per pixel), so rare bright materials are learnt (`losses.balanced_l1`).
    """

    adversarial: float = 1.0
    cycle: float = 10.0
    physics: float = 1.0
    identity: float = 5.0
    style: float = 1.0
    identity_balance: float = 0.0


@dataclass(frozen=True, slots=True)
class TrainConfig:
    """One training run.

    Attributes:
        name: model name; the weight file is `output` and the run folder `runs/<name>`.
        kind: "sensor" or "weather".
        pairs: the source -> target pairs.
        output: weight file to write (relative to the repo root unless absolute).
        range_exponent: n of I_P.
        steps, batch, crop_width: optimisation length, frames per domain per step, and the
            azimuth crop (pixels) taken from each frame per sample.
        lr, betas: Adam settings for all four networks (paper: 1e-5, (0.5, 0.999)).
        base, blocks: generator width and residual blocks; disc_base: critic width.
        seed: torch and sampling seed.
        checkpoint_every: steps between resumable checkpoints.
        losses: LossWeights.
        workers: parallel jobs for building the cache.
    """

    name: str
    kind: str
    pairs: tuple[PairSpec, ...]
    output: str
    range_exponent: float = 1.0
    steps: int = 2000
    batch: int = 4
    crop_width: int = 256
    lr: float = 2e-4
    betas: tuple[float, float] = (0.5, 0.999)
    base: int = 16
    blocks: int = 3
    disc_base: int = 16
    seed: int = 42
    checkpoint_every: int = 200
    losses: LossWeights = LossWeights()
    workers: int = 2
    description: str = ""

    def output_path(self) -> Path:
        p = Path(self.output).expanduser()
        return p if p.is_absolute() else REPO_ROOT / p

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def data_hash(self) -> str:
        """Hash of everything that decides the cached inputs (not the optimisation)."""
        payload = {"pairs": [asdict(p) for p in self.pairs], "n": self.range_exponent}
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


_TOP = {
    "schema_version", "name", "kind", "description", "pairs", "output", "range_exponent",
    "steps", "batch", "crop_width", "lr", "betas", "base", "blocks", "disc_base", "seed",
    "checkpoint_every", "losses", "workers",
}  # fmt: skip
_DOMAIN = set(DomainSpec.__dataclass_fields__)
_LOSSES = set(LossWeights.__dataclass_fields__)


def load_train_config(path: str | Path) -> TrainConfig:
    """Read and validate a training config. Raises ConfigError naming the file and key."""
    p = Path(path)
    if not p.is_file():
        candidate = TRAIN_DIR / f"{path}.yaml"
        if candidate.is_file():
            p = candidate
        else:
            known = sorted(q.stem for q in TRAIN_DIR.glob("*.yaml"))
            raise ConfigError(f"{path}: training config not found; shipped configs: {known}.")
    try:
        raw = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{p}: cannot read the training config: {exc}") from None
    return parse_train_config(raw, str(p))


def parse_train_config(raw: Any, where: str) -> TrainConfig:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping at the top level.")
    _reject(raw, _TOP, where)
    for key in ("name", "kind", "pairs", "output"):
        if key not in raw:
            raise ConfigError(f"{where}: missing key '{key}'.")
    kind = raw["kind"]
    if kind not in KINDS:
        raise ConfigError(f"{where}: kind {kind!r}; expected one of {KINDS}.")
    pairs_raw = raw["pairs"]
    if not isinstance(pairs_raw, dict) or not pairs_raw:
        raise ConfigError(f"{where}: 'pairs' must map keys to {{source, target}} entries.")
    pairs = []
    for key, entry in pairs_raw.items():
        ctx = f"{where}: pairs.{key}"
        if kind == "weather" and key not in STYLES:
            raise ConfigError(f"{ctx}: weather pairs are keyed by style, one of {STYLES}.")
        if not isinstance(entry, dict) or set(entry) != {"source", "target"}:
            raise ConfigError(f"{ctx}: expected exactly the keys 'source' and 'target'.")
        pairs.append(PairSpec(str(key), _domain(entry["source"], f"{ctx}.source"),
                              _domain(entry["target"], f"{ctx}.target")))  # fmt: skip
    if kind == "sensor" and len(pairs) != 1:
        raise ConfigError(f"{where}: a sensor model has exactly one pair, got {len(pairs)}.")
    losses_raw = raw.get("losses", {}) or {}
    _reject(losses_raw, _LOSSES, f"{where}: losses")
    losses = LossWeights(**{k: float(v) for k, v in losses_raw.items()})
    scalars = {k: raw[k] for k in _TOP - {"schema_version", "pairs", "losses"} if k in raw}
    if "betas" in scalars:
        scalars["betas"] = tuple(float(b) for b in scalars["betas"])
    try:
        cfg = TrainConfig(pairs=tuple(pairs), losses=losses, **scalars)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    for name in ("steps", "batch", "crop_width", "base", "blocks", "checkpoint_every", "workers"):
        value = getattr(cfg, name)
        if not isinstance(value, int) or value < 1:
            raise ConfigError(f"{where}: {name} = {value!r}; expected a positive integer.")
    if cfg.crop_width % 4:
        raise ConfigError(f"{where}: crop_width {cfg.crop_width} must be a multiple of 4.")
    return cfg


def _domain(raw: Any, where: str) -> DomainSpec:
    if not isinstance(raw, dict) or "dataset" not in raw:
        raise ConfigError(f"{where}: expected a mapping with at least 'dataset'.")
    _reject(raw, _DOMAIN, where)
    values = dict(raw)
    values["holdout"] = tuple(values.get("holdout", ()) or ())
    values["weather"] = dict(values.get("weather", {}) or {})
    spec = DomainSpec(**values)
    if spec.dataset != "synth" and spec.root is None:
        raise ConfigError(f"{where}: dataset {spec.dataset!r} needs a 'root'.")
    if spec.weather and spec.weather.get("stage") not in STYLES:
        raise ConfigError(f"{where}: weather.stage must be one of {STYLES}.")
    return spec


def _reject(mapping: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(mapping) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown}; allowed: {sorted(allowed)}.")
