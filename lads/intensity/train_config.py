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

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from lads.errors import ConfigError
from lads.intensity.splits import SPLITS

# The config's value types live in train_spec; importers take them from here too.
from lads.intensity.train_spec import RUNS_DIR as RUNS_DIR
from lads.intensity.train_spec import DomainSpec as DomainSpec
from lads.intensity.train_spec import LossWeights as LossWeights
from lads.intensity.train_spec import PairSpec as PairSpec
from lads.intensity.train_spec import TrainConfig as TrainConfig
from lads.intensity.train_spec import weather_physics_version as weather_physics_version
from lads.resources import train_configs_dir

KINDS = ("sensor", "weather")
# Where relative dataset roots of a training config are taken from, unless --data-root.
DATA_ROOT_ENV = "LADS_DATA"
# The generator architectures (`lads.intensity.model`): a U-Net on the range image, or an MLP
# on each point's own inputs and its fitted law.
ARCHITECTURES: tuple[str, ...] = ("unet", "pointwise")
# What keys the fitted law's intercepts (`lads.intensity.law_groups`).
LAW_GROUPS: tuple[str, ...] = ("material", "class")
_TOP = {
    "schema_version", "name", "kind", "description", "pairs", "output", "range_exponent",
    "steps", "batch", "crop_width", "lr", "betas", "base", "blocks", "disc_base", "seed",
    "checkpoint_every", "losses", "workers", "residual", "architecture", "point_width",
    "point_layers", "identity_points", "lr_decay_from", "law_input", "law_groups",
    "material_min_points",
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
    if base is not None and not Path(base).expanduser().is_dir():
        named = "--data-root" if data_root else f"${DATA_ROOT_ENV}"
        raise ConfigError(
            f"{base}: no such folder ({named}); pass the folder that holds the datasets "
            "(semantickitti/, nuscenes-scene0001/, wads/, ...)."
        )
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
            folders = ", ".join(f"{r}/" for r in roots)
            raise ConfigError(
                f"{where}: {ctx}.root is {domain.root!r}, relative to a data root: pass "
                f"--data-root DIR (the folder that holds {folders}) or set {DATA_ROOT_ENV}."
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
    """A validated TrainConfig of a YAML mapping; `where` names the file in errors.

    Raises:
        ConfigError: a schema error naming the key.
    """
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping at the top level.")
    _reject(raw, _TOP, where)
    for key in ("name", "kind", "pairs"):
        if key not in raw:
            raise ConfigError(f"{where}: missing key '{key}'.")
    kind = raw["kind"]
    if kind not in KINDS:
        raise ConfigError(f"{where}: kind {kind!r}; expected one of {KINDS}.")
    pairs = _pairs(raw["pairs"], kind, where)
    losses_raw = raw.get("losses", {}) or {}
    _reject(losses_raw, _LOSSES, f"{where}: losses")
    losses = LossWeights(**{k: float(v) for k, v in losses_raw.items()})
    scalars = {k: raw[k] for k in _TOP - {"schema_version", "pairs", "losses"} if k in raw}
    if "betas" in scalars:
        scalars["betas"] = tuple(float(b) for b in scalars["betas"])
    try:
        cfg = TrainConfig(pairs=pairs, losses=losses, **scalars)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    _check_settings(cfg, where)
    return cfg


def _pairs(pairs_raw: Any, kind: str, where: str) -> tuple[PairSpec, ...]:
    """The pairs of the `pairs` mapping of a config of `kind`."""
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
    return tuple(pairs)


def _check_settings(cfg: TrainConfig, where: str) -> None:
    """Refuse sizes, schedules and architecture settings out of range or inconsistent."""
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
    if cfg.law_groups not in LAW_GROUPS:
        raise ConfigError(
            f"{where}: law_groups = {cfg.law_groups!r}; expected one of {list(LAW_GROUPS)}."
        )
    if cfg.law_groups == "class" and not cfg.residual:
        raise ConfigError(f"{where}: law_groups: class keys the fitted law; set residual: true.")
    if not isinstance(cfg.law_input, bool):
        raise ConfigError(f"{where}: law_input = {cfg.law_input!r}; expected true or false.")
    if not cfg.law_input and cfg.architecture != "pointwise":
        raise ConfigError(f"{where}: law_input: false needs architecture: pointwise.")
    least = cfg.material_min_points
    if not isinstance(least, int) or isinstance(least, bool) or least < 0:
        raise ConfigError(
            f"{where}: material_min_points = {least!r}; expected a non-negative integer."
        )
    if cfg.architecture == "pointwise" and not cfg.residual:
        raise ConfigError(
            f"{where}: the pointwise generator corrects the fitted law; set residual: true."
        )


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
