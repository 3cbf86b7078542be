"""The value types of a training config (`lads.intensity.train_config` reads them from YAML):
the domains, the source -> target pairs, the loss weights and the run settings."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from lads.intensity.splits import merged_view

# Where a run folder goes by default, under the working directory.
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
        law_groups: "material" (the law's intercepts per material, for frames of any
            label set) or "class" (per class of the target's label set where a class has
            enough training points, the material otherwise; `lads.intensity.law_groups`).
        law_input: whether the pointwise generator reads the fitted law's value. Without
            it the correction is a function of material and geometry alone, added to the
            law, so a class whose law intercept training never showed beside its material
            (a pooled intercept) is not an input the network extrapolates on.
        material_min_points: a material seen on fewer points of the labelled target
            training frames (summed over pairs) keeps the zero vector of an unseen
            material: its learned vector would rest on too few points to carry to another
            place. 0: every material present learns its vector.
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
    law_input: bool = True
    law_groups: str = "material"
    material_min_points: int = 0
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
