"""The networks of one intensity training run: the generator G_S2T, the inverse G_T2S and the
critics, with the fitted laws a residual generator corrects (docs/intensity.md §4)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, cast

import torch

from lads.intensity.checkpoint import MATERIAL_DIMS
from lads.intensity.features import NORMALISED_CHANNELS, STYLES, channel_names
from lads.intensity.law_reference import TorchLaw
from lads.intensity.model import Discriminator, Generator, make_generator
from lads.intensity.train_config import TrainConfig
from lads.physics.materials import material_names

GEOMETRY = ("ln_range", "cos_incidence", "elevation", "mask")


class Nets(torch.nn.Module):
    """G_S2T, G_T2S and the critics of one run."""

    def __init__(self, cfg: TrainConfig, labelled_targets: dict[str, bool]) -> None:
        super().__init__()
        weather = cfg.kind == "weather"
        self.channels = channel_names(weather)
        styles = STYLES if weather else ()
        size, depth = cfg.generator_size
        self.g = make_generator(
            cfg.architecture,
            self.channels,
            NORMALISED_CHANNELS,
            size=size,
            depth=depth,
            materials=len(material_names()),
            material_dims=MATERIAL_DIMS,
            law_input=cfg.law_input,
        )
        self.inv_channels = GEOMETRY + ("particle",) + styles + ("z_intensity",)
        self.inv = Generator(
            self.inv_channels, ("ln_range", "cos_incidence"), base=cfg.base, blocks=cfg.blocks
        )
        self.ds_channels = GEOMETRY + styles + ("reflectance",)
        self.d_s = Discriminator(
            self.ds_channels, ("ln_range", "cos_incidence", "reflectance"), cfg.disc_base
        )
        self.dt_channels: dict[str, tuple[str, ...]] = {}
        self.d_t = torch.nn.ModuleDict()
        for pair in cfg.pairs:
            extra = ("reflectance",) if labelled_targets[pair.key] else ()
            names = GEOMETRY + ("particle",) + extra + ("z_intensity",)
            self.dt_channels[pair.key] = names
            self.d_t[pair.key] = Discriminator(
                names, ("ln_range", "cos_incidence", "reflectance"), cfg.disc_base
            )

    def use_laws(
        self,
        laws: dict[str, TorchLaw],
        zstats: dict[str, tuple[float, float, float]],
        residual: bool,
    ) -> None:
        """The fitted law of each target, and whether G predicts a correction to it."""
        self.laws, self.zstats, self.residual = laws, zstats, residual

    def translate(
        self,
        raw: torch.Tensor,
        mask: torch.Tensor,
        key: str,
        extinction: torch.Tensor,
        classes: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """G_S2T in target `key`'s z-space: G's output, plus the target's fitted law when the
        run is residual (`TrainConfig.residual`); a pointwise G also sees the law. `classes`
        (B, 1, H, W) class ids per pixel, for a law keyed by class."""
        if not self.residual:
            return self.g(raw, mask)
        mean, std, _ = self.zstats[key]
        law = (self.laws[key].ln_reference(raw, extinction, classes) - mean) / std
        return self.g(raw, mask, law) + law

    def hold_rare_materials(self, counts: dict[int, int], min_points: int) -> tuple[str, ...]:
        """Keep at zero, for the whole run, the learned vector of every material with fewer
        than `min_points` training points (`counts`: material index -> points); returns the
        names of the materials held. Zero gradients leave Adam's update at exactly 0."""
        table = getattr(self.g, "material_embedding", None)
        if table is None or min_points <= 0:
            return ()
        names = material_names()
        held = [i for i in range(len(names)) if counts.get(i, 0) < min_points]
        keep = torch.ones(table.weight.shape[0], 1, device=table.weight.device)
        keep[[i + 1 for i in held]] = 0.0  # row 0 is the empty pixel's
        table.weight.register_hook(lambda grad: grad * keep)
        return tuple(names[i] for i in held)

    def pick(
        self, raw: torch.Tensor, names: tuple[str, ...], **extra: torch.Tensor
    ) -> torch.Tensor:
        """Stack the named channels: from `raw` by name, or given as (B, 1, H, W) tensors."""
        planes = [
            extra[n] if n in extra else raw[:, self.channels.index(n)][:, None] for n in names
        ]
        return torch.cat(planes, 1)


def set_statistics(nets: Nets, stats: Any) -> None:
    """Every network's input normalisation from the run's channel statistics."""
    nets.g.norm.set_stats(stats.mean, stats.std)
    nets.inv.norm.set_stats(stats.mean, stats.std)
    nets.d_s.norm.set_stats(stats.mean, stats.std)
    for d in cast("Iterable[Discriminator]", nets.d_t.values()):  # d_t holds critics only
        d.norm.set_stats(stats.mean, stats.std)
