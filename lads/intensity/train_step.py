"""One optimisation step of `lads train` (`lads.intensity.train`): every pair's generator
terms (the module docstring of `lads.intensity.train` gives the losses), one generator update,
then the critics' LSGAN loss and one critic update."""

from __future__ import annotations

import torch

from lads.errors import TrainingError
from lads.intensity.features import PHYSICS_FLOOR
from lads.intensity.law_reference import TorchLaw
from lads.intensity.losses import balanced_l1, masked_l1, masked_mse_to
from lads.intensity.model import Discriminator
from lads.intensity.sampler import Batch, Sampler
from lads.intensity.train_config import TrainConfig
from lads.intensity.train_nets import Nets
from lads.physics.materials_schema import MAX_REFLECTANCE  # the top of the material scale

# The generator's loss terms, in the order the step reports them.
LOSS_TERMS = ("adversarial", "cycle", "physics", "identity", "style")

# What the critic pass needs of one pair: key, source and target batches, the detached fake
# target intensity (z-space) and the detached reflectance G_T2S gave the real target.
_CriticInputs = tuple[str, Batch, Batch, torch.Tensor, torch.Tensor]


def train_step(
    nets: Nets,
    cfg: TrainConfig,
    sampler: Sampler,
    targets: dict[str, tuple[float, float, float]],
    laws: dict[str, TorchLaw],
    log_k: dict[str, float],
    mean_alpha: dict[str, float],
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer,
    device: str,
) -> dict[str, float]:
    """One generator and one critic update over all pairs; returns the pair-averaged losses.

    targets: per pair key (log_mean, log_std, floor) of the target's z-space; laws: the
    fitted physics law per pair; log_k: ln of the target's calibration k; mean_alpha: mean
    extinction per style (1/m). The result holds each term of LOSS_TERMS, "generator" and
    "critic".
    """
    w = cfg.losses
    parts = {k: 0.0 for k in LOSS_TERMS}
    g_total = torch.zeros((), device=device)
    d_terms: list[_CriticInputs] = []
    for pair in cfg.pairs:
        terms, critic_inputs = _generator_terms(
            nets, cfg, sampler, pair.key, targets, laws, log_k, mean_alpha, device
        )
        g_total = g_total + (
            w.adversarial * terms["adversarial"]
            + w.cycle * terms["cycle"]
            + w.physics * terms["physics"]
            + w.identity * terms["identity"]
            + w.style * terms["style"]
        )
        for name in LOSS_TERMS:
            parts[name] += float(terms[name].detach())
        d_terms.append(critic_inputs)

    opt_g.zero_grad(set_to_none=True)
    g_total.backward()
    opt_g.step()

    d_total = _critic_loss(nets, d_terms, device)
    opt_d.zero_grad(set_to_none=True)
    d_total.backward()
    opt_d.step()
    n = len(cfg.pairs)
    out = {k: v / n for k, v in parts.items()}
    out["generator"] = float(g_total.detach()) / n
    out["critic"] = float(d_total.detach()) / n
    return out


def _generator_terms(
    nets: Nets,
    cfg: TrainConfig,
    sampler: Sampler,
    key: str,
    targets: dict[str, tuple[float, float, float]],
    laws: dict[str, TorchLaw],
    log_k: dict[str, float],
    mean_alpha: dict[str, float],
    device: str,
) -> tuple[dict[str, torch.Tensor], _CriticInputs]:
    """The unweighted generator terms of pair `key` on fresh batches, and the critics' inputs."""
    mean, std, _ = targets[key]
    s = _to(sampler.batch(key, "source", cfg.batch, cfg.crop_width, targets[key]), device)
    t = _to(sampler.batch(key, "target", cfg.batch, cfg.crop_width, targets[key]), device)
    t_z = _intensity(t, key)
    fake = nets.translate(s.raw, s.mask, key, s.extinction, s.classes) * s.mask
    # Physics reference: the law fitted to this target's training frames, in z-space.
    ref = (laws[key].ln_reference(s.raw, s.extinction, s.classes) - mean) / std
    l_phy = masked_l1(fake, ref * s.mask, s.mask)
    l_adv, rho_t = _adversarial_term(nets, key, s, t, t_z, fake)
    l_cyc = _cycle_term(nets, key, s, t, t_z, fake, rho_t)
    l_id = torch.zeros((), device=device)
    if t.labelled:
        l_id = _identity_term(nets, cfg, sampler, key, t, targets[key], device)
    l_style = torch.zeros((), device=device)
    if cfg.kind == "weather" and len(cfg.pairs) > 1:
        other = next(p.key for p in cfg.pairs if p.key != key)
        l_style = _style_term(nets, s, fake, key, other, targets, log_k, mean_alpha)
    terms = {
        "adversarial": l_adv,
        "cycle": l_cyc,
        "physics": l_phy,
        "identity": l_id,
        "style": l_style,
    }
    return terms, (key, s, t, fake.detach(), rho_t.detach())


def _intensity(batch: Batch, key: str) -> torch.Tensor:
    """The batch's target intensity (z-space); refuses target frames without one."""
    if batch.z is None:
        raise TrainingError(f"pair {key}: target frames carry no intensity.")
    return batch.z


def _adversarial_term(
    nets: Nets, key: str, s: Batch, t: Batch, t_z: torch.Tensor, fake: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """LSGAN generator term of both critics, and the reflectance (B, 1, H, W) G_T2S gives the
    real target (masked)."""
    fake_in = nets.pick(s.raw, nets.dt_channels[key], z_intensity=fake)
    l_adv = masked_mse_to(nets.d_t[key](fake_in, s.mask), 1.0, Discriminator.patch_mask(s.mask))
    inv_t = nets.pick(t.raw, nets.inv_channels, z_intensity=t_z)
    rho_t = MAX_REFLECTANCE * torch.sigmoid(nets.inv(inv_t, t.mask)) * t.mask
    ds_fake = nets.pick(t.raw, nets.ds_channels, reflectance=rho_t)
    l_adv = l_adv + masked_mse_to(nets.d_s(ds_fake, t.mask), 1.0, Discriminator.patch_mask(t.mask))
    return l_adv, rho_t


def _cycle_term(
    nets: Nets,
    key: str,
    s: Batch,
    t: Batch,
    t_z: torch.Tensor,
    fake: torch.Tensor,
    rho_t: torch.Tensor,
) -> torch.Tensor:
    """Source cycle (G_T2S(fake) ~ source reflectance) plus target cycle (G_S2T of the target
    rebuilt with G_T2S's reflectance ~ real intensity)."""
    ch = nets.channels
    inv_s = nets.pick(s.raw, nets.inv_channels, z_intensity=fake)
    rho_s = MAX_REFLECTANCE * torch.sigmoid(nets.inv(inv_s, s.mask))
    l_cyc = masked_l1(rho_s, s.raw[:, ch.index("reflectance")][:, None], s.mask)
    geometry = torch.exp(t.raw[:, ch.index("ln_geometry")][:, None])
    rebuilt = t.raw.clone()
    rebuilt[:, ch.index("reflectance")] = rho_t[:, 0]
    rebuilt[:, ch.index("ln_physics")] = torch.log(rho_t * geometry + PHYSICS_FLOOR)[:, 0]
    rebuilt = rebuilt * t.mask
    return l_cyc + masked_l1(
        nets.translate(rebuilt, t.mask, key, t.extinction, t.classes), t_z, t.mask
    )


def _identity_term(
    nets: Nets,
    cfg: TrainConfig,
    sampler: Sampler,
    key: str,
    t: Batch,
    target: tuple[float, float, float],
    device: str,
) -> torch.Tensor:
    """G_S2T(target's own physics inputs) ~ real intensity, material-balanced; on the crops
    `t`, or on `cfg.identity_points` points drawn afresh."""
    ti = t
    if cfg.identity_points is not None:
        ti = _to(sampler.points(key, cfg.identity_points, target), device)
    ti_z = _intensity(ti, key)
    return balanced_l1(
        nets.translate(ti.raw, ti.mask, key, ti.extinction, ti.classes),
        ti_z,
        ti.mask,
        ti.raw[:, nets.channels.index("material")][:, None],
        cfg.losses.identity_balance,
    )


def _critic_loss(nets: Nets, d_terms: list[_CriticInputs], device: str) -> torch.Tensor:
    """LSGAN loss of the target critics (real target vs fake) and the source critic (real
    source vs the target's G_T2S reflectance), summed over pairs."""
    d_total = torch.zeros((), device=device)
    for key, s, t, fake, rho_t in d_terms:
        t_z = _intensity(t, key)  # refused in the generator pass already
        d_t, names = nets.d_t[key], nets.dt_channels[key]
        pm_s, pm_t = Discriminator.patch_mask(s.mask), Discriminator.patch_mask(t.mask)
        real_in = nets.pick(t.raw, names, z_intensity=t_z)
        fake_in = nets.pick(s.raw, names, z_intensity=fake)
        d_total = d_total + 0.5 * (
            masked_mse_to(d_t(real_in, t.mask), 1.0, pm_t)
            + masked_mse_to(d_t(fake_in, s.mask), 0.0, pm_s)
        )
        real_s = nets.pick(s.raw, nets.ds_channels)
        fake_s = nets.pick(t.raw, nets.ds_channels, reflectance=rho_t)
        d_total = d_total + 0.5 * (
            masked_mse_to(nets.d_s(real_s, s.mask), 1.0, pm_s)
            + masked_mse_to(nets.d_s(fake_s, t.mask), 0.0, pm_t)
        )
    return d_total


def _style_term(
    nets: Nets,
    s: Batch,
    fake: torch.Tensor,
    key: str,
    other: str,
    targets: dict[str, tuple[float, float, float]],
    log_k: dict[str, float],
    mean_alpha: dict[str, float],
) -> torch.Tensor:
    """Multi-style consistency: the same geometry under another style must differ, in
    calibrated log intensity, by that style's two-way extinction and nothing else."""
    ch = nets.channels
    range_m = torch.exp(s.raw[:, ch.index("ln_range")][:, None])
    alpha_a = s.extinction.view(-1, 1, 1, 1)
    alpha_b = torch.full_like(alpha_a, mean_alpha[other])
    shift = -2.0 * (alpha_b - alpha_a) * range_m
    swapped = s.raw.clone()
    swapped[:, ch.index(key)] = 0.0
    swapped[:, ch.index(other)] = s.mask[:, 0]
    for name in ("ln_physics", "ln_geometry"):
        swapped[:, ch.index(name)] = s.raw[:, ch.index(name)] + shift[:, 0]
    swapped = swapped * s.mask
    fake_b = nets.translate(swapped, s.mask, other, alpha_b.view(-1), s.classes)
    (ma, sa, _), (mb, sb, _) = targets[key], targets[other]
    lnq_a = fake * sa + ma - log_k[key]
    lnq_b = fake_b * sb + mb - log_k[other]
    return masked_l1(lnq_b - lnq_a, shift, s.mask)


def _to(batch: Batch, device: str) -> Batch:
    """`batch` on `device` (itself on the CPU)."""
    if device == "cpu":
        return batch
    return Batch(
        batch.raw.to(device),
        batch.mask.to(device),
        None if batch.z is None else batch.z.to(device),
        batch.labelled,
        batch.extinction.to(device),
        batch.classes,  # read on the CPU by the fitted law
    )
