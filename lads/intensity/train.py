"""`lads train CONFIG`: unpaired, physics-informed training of an intensity generator.

Per pair (source simulation -> target recordings) and step:

    fake     = G_S2T(source physics inputs)                      target intensity, z-space
    L_adv    = LSGAN(D_T[pair] on (geometry, fake)) + LSGAN(D_S on (geometry, G_T2S(real)))
    L_cycle  = |G_T2S(fake) - rho_source| + |G_S2T(rebuilt with G_T2S(real)) - real|
    L_phy    = |fake - z(law)|, law = the physics law fitted per material to the target's
               training frames (`law_reference`, `fitted_physics`), in the target's units
    (residual runs: fake = G_S2T(...) + z(law), so G learns a correction to the law)
    L_id     = |G_S2T(target's own physics inputs) - real|        (labelled targets only)
    L_style  = |(ln q_w - ln q_w') + 2 (alpha_w - alpha_w') R|     (weather, >= 2 styles)

with q = refl / k the calibrated intensity. The critics see geometry with the intensity, so
they judge intensity *given* range, incidence and material. G_T2S maps (geometry, target
intensity) to material reflectance, which makes the real-domain cycle well posed.

The run folder (`runs/<name>/` by default) holds the cache, `statistics.json`
(`run_statistics`), `checkpoints/latest.pt`
(networks, optimisers, random states, loss history; written atomically every
`checkpoint_every` steps, so a killed run resumes where it stopped), `loss.png` and
`history.json`. The weight file (`--output`) holds the generator of the checkpoint that
scored best on the validation split (`selection`), the last one when there is none.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from lads.errors import TrainingError
from lads.files import atomic_copy, atomic_write
from lads.intensity.cache import build_cache, iter_frames
from lads.intensity.cache_statistics import Statistics
from lads.intensity.checkpoint import (
    MATERIAL_DIMS,
    IntensityModel,
    ModelMeta,
    TargetSpec,
    save_model,
)
from lads.intensity.features import (
    FEATURE_VERSION,
    PHYSICS_FLOOR,
    channel_names,
)
from lads.intensity.law_reference import TorchLaw, fit_law
from lads.intensity.losses import balanced_l1, masked_l1, masked_mse_to
from lads.intensity.model import Discriminator
from lads.intensity.run_statistics import run_statistics
from lads.intensity.sampler import Batch, Sampler
from lads.intensity.selection import BEST, Selector, score, validation_frames
from lads.intensity.train_config import TrainConfig
from lads.intensity.train_nets import Nets, set_statistics
from lads.intensity.train_state import resume, save_checkpoint, write_loss_figure
from lads.physics.materials import material_names
from lads.physics.materials_schema import MAX_REFLECTANCE  # the top of the material scale

CHECKPOINT = "checkpoints/latest.pt"


def train(
    cfg: TrainConfig,
    *,
    run_dir: Path | None = None,
    device: str = "cpu",
    progress: bool = True,
    max_steps: int | None = None,
) -> dict[str, Any]:
    """Prepare the cache, train (resuming a checkpoint), write the weights; returns a summary.

    The physics reference of L_phy is the law fitted to each target's training frames
    (`law_reference`); every checkpoint is scored on the validation frames and the best one
    becomes the weight file (`selection`). `max_steps` stops early (for tests and
    interrupted runs) without writing the weights.

    Raises:
        TrainingError: unusable data, a checkpoint of another config, or a diverged run.
    """
    run = cfg.run_path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    jobs = build_cache(run, cfg, progress=progress)
    channels = channel_names(cfg.kind == "weather")
    facts = run_statistics(run, cfg, jobs, channels)
    stats, labelled, mean_alpha = facts.stats, facts.labelled, facts.mean_alpha
    laws = {}
    for p in cfg.pairs:
        target_jobs = [j for j in jobs if j.pair == p.key and j.role == "target"]
        laws[p.key] = fit_law(iter_frames(run, target_jobs), stats.targets[p.key]["floor"])
    torch_laws = {k: TorchLaw.of(law, channels) for k, law in laws.items()}

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    nets = Nets(cfg, labelled)
    set_statistics(nets, stats)
    nets.to(device)
    gen_params = list(nets.g.parameters()) + list(nets.inv.parameters())
    disc_params = list(nets.d_s.parameters()) + list(nets.d_t.parameters())
    opt_g = torch.optim.Adam(gen_params, lr=cfg.lr, betas=cfg.betas)
    opt_d = torch.optim.Adam(disc_params, lr=cfg.lr, betas=cfg.betas)
    sampler = Sampler(run, jobs, rng)
    history: list[dict[str, float]] = []
    start = 0
    ckpt_path = run / CHECKPOINT
    # Length and checkpoint spacing may change between runs: a run can be extended.
    resumable = {k: v for k, v in cfg.to_dict().items() if k not in ("steps", "checkpoint_every")}
    resumable["data_hash"] = cfg.data_hash()  # checkpoints of other source frames never resume
    config_id = json.dumps(resumable, sort_keys=True, default=str)
    if ckpt_path.is_file():
        start, history = resume(ckpt_path, config_id, nets, opt_g, opt_d, rng)

    targets = {k: (v["log_mean"], v["log_std"], v["floor"]) for k, v in stats.targets.items()}
    log_k = {k: v["log_k"] for k, v in stats.targets.items()}
    nets.use_laws(torch_laws, targets, cfg.residual)
    record = {
        "laws": {k: law.to_json() for k, law in laws.items()},
        "jobs": len(jobs),
        "data_hash": cfg.data_hash(),
    }
    validation = validation_frames(cfg)
    selector = Selector(run, config_id, resumed=start > 0)
    end = cfg.steps if max_steps is None else min(cfg.steps, max_steps)
    if start == 0 and cfg.residual:
        # The untrained residual generator outputs 0, i.e. the fitted law alone: training
        # must beat it on validation to be chosen.
        _offer(
            nets, selector, _meta(cfg, stats, channels, record, history, 0), validation, 0, device
        )
    bar = tqdm(
        range(start, end),
        initial=start,
        total=cfg.steps,
        desc=f"train {cfg.name}",
        unit="step",
        disable=not progress,
    )
    for step in bar:
        for opt in (opt_g, opt_d):
            for group in opt.param_groups:
                group["lr"] = learning_rate(cfg, step)
        losses = _step(
            nets, cfg, sampler, targets, torch_laws, log_k, mean_alpha, opt_g, opt_d, device
        )
        if not all(math.isfinite(v) for v in losses.values()):
            raise TrainingError(
                f"{cfg.name}: loss became NaN/inf at step {step} ({losses}); lower lr in the "
                f"config and restart (delete {ckpt_path} to start over)."
            )
        history.append(losses)
        bar.set_postfix(g=f"{losses['generator']:.3f}", d=f"{losses['critic']:.3f}")
        done = step + 1
        if done % cfg.checkpoint_every == 0 or done == end:
            save_checkpoint(ckpt_path, config_id, done, nets, opt_g, opt_d, rng, history)
            write_loss_figure(history, run / "loss.png", cfg.name)
            meta = _meta(cfg, stats, channels, record, history, done)
            _offer(nets, selector, meta, validation, done, device)
    atomic_write(run / "history.json", json.dumps(history).encode())
    summary: dict[str, Any] = {
        "run_dir": str(run),
        "steps_done": len(history),
        "selection": selector.record.get("best"),
    }
    if len(history) < cfg.steps:
        return summary
    weights = cfg.output_path(run)
    best = selector.best_step
    if best is None:  # no validation frames: the last step is the model
        nets.g.cpu()
        save_model(weights, _meta(cfg, stats, channels, record, history, len(history)), nets.g)
    else:
        atomic_copy(run / BEST, weights)
    summary["weights"] = str(weights)
    summary["selected_step"] = best if best is not None else len(history)
    return summary


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """The learning rate at `step` (0-based): `cfg.lr`, falling linearly to 0 at the last
    step from `lr_decay_from` x steps on when that is set. A function of the step alone, so a
    resumed run follows the same schedule."""
    if cfg.lr_decay_from is None:
        return cfg.lr
    start = cfg.lr_decay_from * cfg.steps
    if step < start:
        return cfg.lr
    return cfg.lr * max(cfg.steps - step, 0) / max(cfg.steps - start, 1.0)


def _offer(
    nets: Nets,
    selector: Selector,
    meta: ModelMeta,
    validation: dict[str, list[Any]],
    step: int,
    device: str,
) -> None:
    """Score the generator as it is at `step` on the validation frames and offer it."""
    nets.g.cpu().eval()
    scores = score(IntensityModel(meta, nets.g, f"{meta.name} step {step}"), validation)
    selector.offer(step, meta, nets.g, scores)
    nets.g.train().to(device)


def _meta(
    cfg: TrainConfig,
    stats: Statistics,
    channels: tuple[str, ...],
    record: dict[str, Any],
    history: list[dict[str, float]],
    step: int,
) -> ModelMeta:
    """The metadata of the generator at `step`."""
    return ModelMeta(
        name=cfg.name,
        kind=cfg.kind,
        channels=channels,
        feature_version=FEATURE_VERSION,
        range_exponent=cfg.range_exponent,
        base=cfg.generator_size[0],
        blocks=cfg.generator_size[1],
        targets={
            k: TargetSpec(**v, law=record["laws"][k] if cfg.residual else None)
            for k, v in stats.targets.items()
        },
        calibration=stats.calibration,
        materials=material_names(),
        material_dims=MATERIAL_DIMS,
        architecture=cfg.architecture,
        training={
            "config": cfg.to_dict(),
            "steps": step,
            "seed": cfg.seed,
            "final_losses": history[step - 1] if history else {},
            "loss_shares": _loss_shares(cfg, history[max(0, step - 100) : step]),
            "physics_reference": record["laws"],
            "cache_frames": record["jobs"],
            "data_hash": record["data_hash"],
        },
    )


def _loss_shares(cfg: TrainConfig, recent: list[dict[str, float]]) -> dict[str, float]:
    """Each weighted generator term's share of the generator loss over `recent` steps."""
    w = cfg.losses
    weights = {
        "adversarial": w.adversarial,
        "cycle": w.cycle,
        "physics": w.physics,
        "identity": w.identity,
        "style": w.style,
    }
    parts = {
        k: weights[k] * float(np.mean([h.get(k, 0.0) for h in recent])) if recent else 0.0
        for k in weights
    }
    total = sum(parts.values())
    return {k: v / total for k, v in parts.items()} if total > 0 else parts


def _step(
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
    w = cfg.losses
    ch = nets.channels
    parts = {k: 0.0 for k in ("adversarial", "cycle", "physics", "identity", "style")}
    g_total = torch.zeros((), device=device)
    d_terms = []
    for pair in cfg.pairs:
        key = pair.key
        mean, std, floor = targets[key]
        s = _to(sampler.batch(key, "source", cfg.batch, cfg.crop_width, targets[key]), device)
        t = _to(sampler.batch(key, "target", cfg.batch, cfg.crop_width, targets[key]), device)
        if t.z is None:
            raise TrainingError(f"pair {key}: target frames carry no intensity.")
        fake = nets.translate(s.raw, s.mask, key, s.extinction) * s.mask
        # Physics reference: the law fitted to this target's training frames, in z-space.
        ref = (laws[key].ln_reference(s.raw, s.extinction) - mean) / std
        l_phy = masked_l1(fake, ref * s.mask, s.mask)

        d_t = nets.d_t[key]
        dt_names = nets.dt_channels[key]
        fake_in = nets.pick(s.raw, dt_names, z_intensity=fake)
        l_adv = masked_mse_to(d_t(fake_in, s.mask), 1.0, Discriminator.patch_mask(s.mask))
        inv_t = nets.pick(t.raw, nets.inv_channels, z_intensity=t.z)
        rho_t = MAX_REFLECTANCE * torch.sigmoid(nets.inv(inv_t, t.mask)) * t.mask
        ds_fake = nets.pick(t.raw, nets.ds_channels, reflectance=rho_t)
        l_adv = l_adv + masked_mse_to(
            nets.d_s(ds_fake, t.mask), 1.0, Discriminator.patch_mask(t.mask)
        )

        inv_s = nets.pick(s.raw, nets.inv_channels, z_intensity=fake)
        rho_s = MAX_REFLECTANCE * torch.sigmoid(nets.inv(inv_s, s.mask))
        l_cyc = masked_l1(rho_s, s.raw[:, ch.index("reflectance")][:, None], s.mask)
        geometry = torch.exp(t.raw[:, ch.index("ln_geometry")][:, None])
        rebuilt = t.raw.clone()
        rebuilt[:, ch.index("reflectance")] = rho_t[:, 0]
        rebuilt[:, ch.index("ln_physics")] = torch.log(rho_t * geometry + PHYSICS_FLOOR)[:, 0]
        rebuilt = rebuilt * t.mask
        l_cyc = l_cyc + masked_l1(nets.translate(rebuilt, t.mask, key, t.extinction), t.z, t.mask)

        l_id = torch.zeros((), device=device)
        if t.labelled:
            ti = t
            if cfg.identity_points is not None:
                ti = _to(sampler.points(key, cfg.identity_points, targets[key]), device)
            if ti.z is None:
                raise TrainingError(f"pair {key}: target frames carry no intensity.")
            l_id = balanced_l1(
                nets.translate(ti.raw, ti.mask, key, ti.extinction),
                ti.z,
                ti.mask,
                ti.raw[:, ch.index("material")][:, None],
                w.identity_balance,
            )

        l_style = torch.zeros((), device=device)
        if cfg.kind == "weather" and len(cfg.pairs) > 1:
            other = next(p.key for p in cfg.pairs if p.key != key)
            l_style = _style_term(nets, s, fake, key, other, targets, log_k, mean_alpha)

        g_total = g_total + (
            w.adversarial * l_adv
            + w.cycle * l_cyc
            + w.physics * l_phy
            + w.identity * l_id
            + w.style * l_style
        )
        for name, value in (
            ("adversarial", l_adv),
            ("cycle", l_cyc),
            ("physics", l_phy),
            ("identity", l_id),
            ("style", l_style),
        ):
            parts[name] += float(value.detach())
        d_terms.append((key, s, t, fake.detach(), rho_t.detach()))

    opt_g.zero_grad(set_to_none=True)
    g_total.backward()
    opt_g.step()

    d_total = torch.zeros((), device=device)
    for key, s, t, fake, rho_t in d_terms:
        if t.z is None:  # refused in the generator pass above
            raise TrainingError(f"pair {key}: target frames carry no intensity.")
        d_t, names = nets.d_t[key], nets.dt_channels[key]
        pm_s, pm_t = Discriminator.patch_mask(s.mask), Discriminator.patch_mask(t.mask)
        real_in = nets.pick(t.raw, names, z_intensity=t.z)
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
    opt_d.zero_grad(set_to_none=True)
    d_total.backward()
    opt_d.step()
    n = len(cfg.pairs)
    out = {k: v / n for k, v in parts.items()}
    out["generator"] = float(g_total.detach()) / n
    out["critic"] = float(d_total.detach()) / n
    return out


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
    fake_b = nets.translate(swapped, s.mask, other, alpha_b.view(-1))
    (ma, sa, _), (mb, sb, _) = targets[key], targets[other]
    lnq_a = fake * sa + ma - log_k[key]
    lnq_b = fake_b * sb + mb - log_k[other]
    return masked_l1(lnq_b - lnq_a, shift, s.mask)


def _to(batch: Batch, device: str) -> Batch:
    if device == "cpu":
        return batch
    return Batch(
        batch.raw.to(device),
        batch.mask.to(device),
        None if batch.z is None else batch.z.to(device),
        batch.labelled,
        batch.extinction.to(device),
    )
