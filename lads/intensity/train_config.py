"""Training configs for the intensity models (`pipelines/train/*.yaml`).

A config names the model, its kind, and one or more *pairs*: an unpaired source domain
(simulation) and a target domain (real recordings) under one key. Sensor models have one
pair keyed by the target's name; weather models have one pair per weather style ("snow",
"fog"), all feeding one style-conditioned generator. Unknown keys are errors.

Data roots: a relative `root` is taken from the *data root*, the folder that holds the
datasets (`--data-root DIR` of `lads train`, else the environment variable `LADS_DATA`); a
config given by path without either takes its own folder. The shipped configs
(`lads/pipelines/train/`, the repository's `pipelines/train/`) name their datasets relative
to it (`semantickitti`, `wads`, ...), so they work wherever lads is installed.

Outputs: training writes into its run folder (`runs/<name>/` under the working directory by
default), the weights as `<run folder>/<name>.pt`, unless `output` (config) or `--output`
(command line) says where; nothing is ever written into the installed package.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from lads.errors import ConfigError
from lads.intensity.splits import SPLITS, merged_view
from lads.resources import train_configs_dir

KINDS = ("sensor", "weather")
# Where relative dataset roots of a training config are taken from, unless --data-root.
DATA_ROOT_ENV = "LADS_DATA"
RUNS_DIR = "runs"


@dataclass(frozen=True, slots=True)
class DomainSpec:
    """Where one domain's frames come from.

    Attributes:
        dataset: a reader name (`lads.readers.READERS`) or "synth" (made here, in memory).
        root: dataset root (None for synth), absolute or relative to `data_root`; several
            roots (a list) are merged into one view (`lads.intensity.splits.merged_view`).
        sensor: sensor profile of the frames (default: the reader's).
        frames: synth only: number of frames; readers: at most this many (0 = all).
        seed: synth street seed; also seeds the weather stage for weather sources.
        split: {"train" | "validation" | "test": shell patterns of frame names}: which
            frames train, which choose (validation) and which judge (test) a model
            (`lads.intensity.splits`); empty = every frame trains.
        weather: for weather sources: the physics stage applied first, e.g.
            {"stage": "snow", "rate_mm_h": 2.5}.
        extinction_per_m: alpha assumed for target recordings in weather (1/m), used in
            their I_P; sources in weather take alpha from the physics stage.
        azimuth_bins: synth only: beams per ring (default the profile's width).
        also: more datasets of the same sensor in this role, each with its own dataset,
            root and split (e.g. a test scene recorded elsewhere, in another layout).
        data_root: the folder a relative `root` is taken from (set when the config is
            loaded, never in the YAML; not part of the data hash).
    """

    dataset: str
    root: str | tuple[str, ...] | None = None
    sensor: str | None = None
    frames: int = 0
    seed: int = 0
    split: dict[str, tuple[str, ...]] = field(default_factory=dict)
    weather: dict[str, Any] = field(default_factory=dict)
    extinction_per_m: float = 0.0
    azimuth_bins: int | None = None
    also: tuple[DomainSpec, ...] = ()
    data_root: str | None = None

    def members(self) -> tuple[tuple[str, DomainSpec], ...]:
        """(tag, domain) of this domain ("") and of each `also` dataset ("also1", ...)."""
        return (("", self), *((f"also{i}", d) for i, d in enumerate(self.also, 1)))

    def root_path(self) -> Path | None:
        """The dataset root (a merged view of several roots), None for synth."""
        if self.root is None:
            return None
        if isinstance(self.root, tuple):
            return merged_view([self._resolve(r) for r in self.root])
        return self._resolve(self.root)

    def _resolve(self, root: str) -> Path:
        p = Path(root).expanduser()
        if p.is_absolute() or self.data_root is None:
            return p
        return (Path(self.data_root) / p).resolve()


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
        name: model name; the run folder defaults to `runs/<name>`.
        kind: "sensor" or "weather".
        pairs: the source -> target pairs.
        output: weight file to write (relative to the working directory); None = `<name>.pt`
            in the run folder.
        range_exponent: n of I_P.
        steps, batch, crop_width: optimisation length, frames per domain per step, and the
            azimuth crop (pixels) taken from each frame per sample.
        lr, betas: Adam settings for all four networks (paper: 1e-5, (0.5, 0.999)).
        architecture: the generator, "unet" (a small U-Net on the range image) or
            "pointwise" (an MLP applied to each point's own inputs and the fitted law's
            value; needs `residual`); `lads.intensity.model`.
        base, blocks: U-Net width and residual blocks (the generator's when it is a U-Net,
            always the inverse generator's); disc_base: critic width.
        point_width, point_layers: the pointwise generator's hidden width and layers.
        lr_decay_from: with a value f in [0, 1), the learning rate falls linearly from `lr`
            at step f x steps to 0 at the last step (CycleGAN's schedule; checkpoints
            late in a run then differ less from one another); None: constant.
        identity_points: pointwise generators only: the identity term draws this many
            occupied pixels at random from all the target's training frames each step
            (independent points, not the critics' azimuth crops: a per-point function
            learns from an unbiased sample of every frame); None: the crops.
        seed: torch and sampling seed.
        checkpoint_every: steps between resumable checkpoints.
        losses: LossWeights.
        workers: parallel jobs for building the cache.
        residual: the generator predicts a correction, in log intensity, to the physics law
            fitted on the target's training frames (and carries that law in its weights),
            instead of the intensity outright.
    """

    name: str
    kind: str
    pairs: tuple[PairSpec, ...]
    output: str | None = None
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
    residual: bool = False
    architecture: str = "unet"
    point_width: int = 32
    point_layers: int = 2
    identity_points: int | None = None
    lr_decay_from: float | None = None

    @property
    def generator_size(self) -> tuple[int, int]:
        """(width, depth) of the generator: (point_width, point_layers) for a pointwise one,
        (base, blocks) for a U-Net; what a weight file records as base and blocks."""
        if self.architecture == "pointwise":
            return self.point_width, self.point_layers
        return self.base, self.blocks

    def run_path(self, run_dir: Path | None = None) -> Path:
        """The run folder: `run_dir`, else `runs/<name>` under the working directory."""
        return Path(run_dir) if run_dir is not None else Path(RUNS_DIR) / self.name

    def output_path(self, run_dir: Path | None = None) -> Path:
        """The weight file this run writes."""
        if self.output is not None:
            return Path(self.output).expanduser()
        return self.run_path(run_dir) / f"{self.name}.pt"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def data_hash(self) -> str:
        """Hash of everything that decides the cached inputs (not the optimisation)."""
        pairs = [asdict(p) for p in self.pairs]
        for pair in pairs:  # where the data lives on this machine does not change them
            for role in ("source", "target"):
                for domain in (pair[role], *pair[role]["also"]):
                    domain.pop("data_root")
        payload: dict[str, Any] = {"pairs": pairs, "n": self.range_exponent}
        if any(p.source.weather or p.target.weather for p in self.pairs):
            # Sources made by the physics weather change with it: stale caches must not match.
            payload["weather_physics"] = weather_physics_version()
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def weather_physics_version() -> str:
    """The weather stage's version (`WEATHER_STAGE_VERSION`): bumped whenever the physics
    changes the bytes a weather stage makes, so it keys anything built from such frames."""
    from lads.stages.weather import WEATHER_STAGE_VERSION  # the stages import this package

    return WEATHER_STAGE_VERSION


# The generator architectures (`lads.intensity.model`): a U-Net on the range image, or an MLP
# on each point's own inputs and its fitted law.
ARCHITECTURES: tuple[str, ...] = ("unet", "pointwise")
_TOP = {
    "schema_version", "name", "kind", "description", "pairs", "output", "range_exponent",
    "steps", "batch", "crop_width", "lr", "betas", "base", "blocks", "disc_base", "seed",
    "checkpoint_every", "losses", "workers", "residual", "architecture", "point_width",
    "point_layers", "identity_points", "lr_decay_from",
}  # fmt: skip
_DOMAIN = set(DomainSpec.__dataclass_fields__) - {"data_root"}
_LOSSES = set(LossWeights.__dataclass_fields__)


def shipped_train_configs() -> list[str]:
    """Names of the training configs shipped with lads."""
    return sorted(q.stem for q in train_configs_dir().glob("*.yaml"))


def load_train_config(path: str | Path, *, data_root: str | Path | None = None) -> TrainConfig:
    """Read and validate a training config: a path, or the name of a shipped config.

    Relative dataset roots are resolved against `data_root`, else $LADS_DATA, else (for a
    config given by path) the config's own folder.

    Raises:
        ConfigError: unknown name or unreadable file, a schema error naming the key, or a
            relative root with no data root to take it from.
    """
    p = Path(path)
    shipped = not p.is_file()
    if shipped:
        candidate = train_configs_dir() / f"{path}.yaml"
        if not candidate.is_file():
            raise ConfigError(
                f"{path}: training config not found; shipped configs: "
                f"{', '.join(shipped_train_configs())}, or pass a path to a YAML file."
            )
        p = candidate
    try:
        raw = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{p}: cannot read the training config: {exc}") from None
    cfg = parse_train_config(raw, str(p))
    base = data_root or os.environ.get(DATA_ROOT_ENV) or (None if shipped else p.parent)
    return resolve_roots(cfg, None if base is None else Path(base), str(p))


def resolve_roots(cfg: TrainConfig, data_root: Path | None, where: str) -> TrainConfig:
    """`cfg` with `data_root` recorded in every domain whose root is relative."""

    def fix(domain: DomainSpec, ctx: str) -> DomainSpec:
        if domain.also:
            also = tuple(fix(d, f"{ctx}.also[{i}]") for i, d in enumerate(domain.also))
            domain = replace(domain, also=also)
        if domain.root is None:
            return domain
        roots = domain.root if isinstance(domain.root, tuple) else (domain.root,)
        if all(Path(r).expanduser().is_absolute() for r in roots):
            return domain
        if data_root is None:
            raise ConfigError(
                f"{where}: {ctx}.root is {domain.root!r}, relative to a data root: pass "
                f"--data-root DIR (the folder that holds {domain.root}/) or set {DATA_ROOT_ENV}."
            )
        return replace(domain, data_root=str(data_root.expanduser().resolve()))

    pairs = tuple(
        replace(
            p,
            source=fix(p.source, f"pairs.{p.key}.source"),
            target=fix(p.target, f"pairs.{p.key}.target"),
        )
        for p in cfg.pairs
    )
    return replace(cfg, pairs=pairs)


def parse_train_config(raw: Any, where: str) -> TrainConfig:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping at the top level.")
    _reject(raw, _TOP, where)
    for key in ("name", "kind", "pairs"):
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
        from lads.intensity.features import STYLES  # numba and scipy: not at CLI start-up

        if kind == "weather" and key not in STYLES:
            raise ConfigError(f"{ctx}: weather pairs are keyed by style, one of {STYLES}.")
        if not isinstance(entry, dict) or set(entry) != {"source", "target"}:
            raise ConfigError(f"{ctx}: expected exactly the keys 'source' and 'target'.")
        pairs.append(
            PairSpec(
                str(key),
                _domain(entry["source"], f"{ctx}.source"),
                _domain(entry["target"], f"{ctx}.target"),
            )
        )
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
    for name in (
        "steps",
        "batch",
        "crop_width",
        "base",
        "blocks",
        "checkpoint_every",
        "workers",
        "point_width",
        "point_layers",
    ):
        value = getattr(cfg, name)
        if not isinstance(value, int) or value < 1:
            raise ConfigError(f"{where}: {name} = {value!r}; expected a positive integer.")
    if cfg.crop_width % 4:
        raise ConfigError(f"{where}: crop_width {cfg.crop_width} must be a multiple of 4.")
    decay = cfg.lr_decay_from
    if decay is not None and not (isinstance(decay, (int, float)) and 0 <= decay < 1):
        raise ConfigError(f"{where}: lr_decay_from = {decay!r}; expected a number in [0, 1).")
    points = cfg.identity_points
    if points is not None and (not isinstance(points, int) or points < 1):
        raise ConfigError(f"{where}: identity_points = {points!r}; expected a positive integer.")
    if points is not None and cfg.architecture != "pointwise":
        raise ConfigError(f"{where}: identity_points needs architecture: pointwise.")
    if cfg.architecture not in ARCHITECTURES:
        raise ConfigError(
            f"{where}: architecture {cfg.architecture!r}; expected one of {list(ARCHITECTURES)}."
        )
    if cfg.architecture == "pointwise" and not cfg.residual:
        raise ConfigError(
            f"{where}: the pointwise generator corrects the fitted law; set residual: true."
        )
    return cfg


def _domain(raw: Any, where: str, nested: bool = False) -> DomainSpec:
    if not isinstance(raw, dict) or "dataset" not in raw:
        raise ConfigError(f"{where}: expected a mapping with at least 'dataset'.")
    if "holdout" in raw:
        raise ConfigError(
            f"{where}: 'holdout' is replaced by 'split' ({{train: [...], validation: [...], "
            "test: [...]}}, frame-name patterns chosen by place); see pipelines/README.md."
        )
    _reject(raw, _DOMAIN, where)
    values = dict(raw)
    if isinstance(values.get("root"), list):
        values["root"] = tuple(str(r) for r in values["root"])
    split = values.get("split") or {}
    if not isinstance(split, dict) or set(split) - set(SPLITS):
        raise ConfigError(
            f"{where}: split must map some of {list(SPLITS)} to lists of frame-name patterns."
        )
    values["split"] = {k: tuple(str(p) for p in (v or ())) for k, v in split.items()}
    values["weather"] = dict(values.get("weather", {}) or {})
    also = values.get("also") or []
    if also and (nested or not isinstance(also, list)):
        raise ConfigError(f"{where}: 'also' is a list of domains, and only one level deep.")
    values["also"] = tuple(_domain(d, f"{where}.also[{i}]", True) for i, d in enumerate(also))
    spec = DomainSpec(**values)
    if spec.dataset != "synth" and spec.root is None:
        raise ConfigError(f"{where}: dataset {spec.dataset!r} needs a 'root'.")
    from lads.intensity.features import STYLES

    if spec.weather and spec.weather.get("stage") not in STYLES:
        raise ConfigError(f"{where}: weather.stage must be one of {STYLES}.")
    return spec


def _reject(mapping: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(mapping) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown}; allowed: {sorted(allowed)}.")
