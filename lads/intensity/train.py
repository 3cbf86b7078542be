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

import functools
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from lads.errors import TrainingError
from lads.files import atomic_copy, atomic_write, make_folder
from lads.intensity.cache import CacheJob, build_cache, iter_frames
from lads.intensity.cache_statistics import Statistics
from lads.intensity.checkpoint import (
    MATERIAL_DIMS,
    IntensityModel,
    ModelMeta,
    TargetSpec,
    save_model,
)
from lads.intensity.features import FEATURE_VERSION, channel_names
from lads.intensity.law_groups import GroupedLaw
from lads.intensity.law_reference import TorchLaw, fit_law
from lads.intensity.run_statistics import run_statistics
from lads.intensity.sampler import Sampler
from lads.intensity.selection import BEST, Selector, score, validation_frames
from lads.intensity.train_config import TrainConfig
from lads.intensity.train_nets import Nets, set_statistics
from lads.intensity.train_state import resume, save_checkpoint, write_loss_figure
from lads.intensity.train_step import train_step
from lads.physics.materials import material_names
from lads.readers import label_set_for

CHECKPOINT = "checkpoints/latest.pt"


def _folders(cfg: TrainConfig, run_dir: Path | None) -> Path:
    """Make the run folder and the weight file's folder before any work (a file in the way
    fails now, not after the training); returns the run folder."""
    make_folder(cfg.output_path(run_dir).parent)
    run = cfg.run_path(run_dir)
    make_folder(run)
    return run


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
    run = _folders(cfg, run_dir)
    jobs = build_cache(run, cfg, progress=progress)
    channels = channel_names(cfg.kind == "weather")
    facts = run_statistics(run, cfg, jobs, channels)
    stats = facts.stats
    laws = _fit_laws(run, cfg, jobs, stats)
    torch_laws = {k: TorchLaw.of(law, channels) for k, law in laws.items()}
    nets, opt_g, opt_d = _networks(cfg, facts.labelled, stats, device)
    held = nets.hold_rare_materials(_material_points(run, jobs), cfg.material_min_points)
    rng = np.random.default_rng(cfg.seed)
    sampler = Sampler(run, jobs, rng)
    ckpt_path = run / CHECKPOINT
    config_id = _config_id(cfg)
    start, history = _resumed(ckpt_path, config_id, nets, opt_g, opt_d, rng)
    targets, log_k = _target_scales(stats)
    nets.use_laws(torch_laws, targets, cfg.residual)
    record = _record(cfg, laws, len(jobs)) | {"materials_held": list(held)}
    meta_at = functools.partial(_meta, cfg, stats, channels, record, history)
    validation = validation_frames(cfg)
    selector = Selector(run, config_id, resumed=start > 0)
    end = cfg.steps if max_steps is None else min(cfg.steps, max_steps)
    if start == 0 and cfg.residual:
        # The untrained residual generator outputs 0, i.e. the fitted law alone: training
        # must beat it on validation to be chosen.
        _offer(nets, selector, meta_at(0), validation, 0, device)
    bar = _progress_bar(cfg, start, end, progress)
    for step in bar:
        _set_learning_rate((opt_g, opt_d), learning_rate(cfg, step))
        losses = train_step(
            nets, cfg, sampler, targets, torch_laws, log_k, facts.mean_alpha, opt_g, opt_d, device
        )
        _check_finite(cfg, step, losses, ckpt_path)
        history.append(losses)
        bar.set_postfix(g=f"{losses['generator']:.3f}", d=f"{losses['critic']:.3f}")
        done = step + 1
        if done % cfg.checkpoint_every == 0 or done == end:
            save_checkpoint(ckpt_path, config_id, done, nets, opt_g, opt_d, rng, history)
            write_loss_figure(history, run / "loss.png", cfg.name)
            _offer(nets, selector, meta_at(done), validation, done, device)
    atomic_write(run / "history.json", json.dumps(history).encode())
    return _finish(cfg, run, nets, selector, meta_at, len(history))


def _fit_laws(
    run: Path, cfg: TrainConfig, jobs: list[CacheJob], stats: Statistics
) -> dict[str, GroupedLaw]:
    """The physics law fitted per material (or class, `cfg.law_groups`) to each pair's
    target training frames, by key."""
    laws = {}
    for p in cfg.pairs:
        target_jobs = [j for j in jobs if j.pair == p.key and j.role == "target"]
        by_class = label_set_for(p.target.dataset) if cfg.law_groups == "class" else None
        floor = stats.targets[p.key]["floor"]
        laws[p.key] = fit_law(iter_frames(run, target_jobs), floor, by_class)
    return laws


def _material_points(run: Path, jobs: list[CacheJob]) -> dict[int, int]:
    """Occupied pixels per material index of the labelled target training frames, summed
    over the pairs: the points the identity term learns each material's vector from."""
    total = np.zeros(len(material_names()) + 1, dtype=np.int64)
    for f in iter_frames(run, [j for j in jobs if j.role == "target"]):
        if not f.labelled:
            continue
        code = np.rint(f.plane("material")[f.plane("mask") > 0]).astype(np.int64)
        total += np.bincount(code, minlength=total.size)[: total.size]
    # Channel code 1 + material index (0: no material).
    return {i - 1: int(n) for i, n in enumerate(total) if i > 0 and n}


def _resumed(
    ckpt_path: Path,
    config_id: str,
    nets: Nets,
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer,
    rng: np.random.Generator,
) -> tuple[int, list[dict[str, float]]]:
    """(steps done, loss history) of the checkpoint, loaded into the run's objects; else (0, [])."""
    return resume(ckpt_path, config_id, nets, opt_g, opt_d, rng) if ckpt_path.is_file() else (0, [])


def _target_scales(
    stats: Statistics,
) -> tuple[dict[str, tuple[float, float, float]], dict[str, float]]:
    """Per pair key: the target's z-space (log_mean, log_std, floor), and its log_k."""
    targets = {k: (v["log_mean"], v["log_std"], v["floor"]) for k, v in stats.targets.items()}
    log_k = {k: v["log_k"] for k, v in stats.targets.items()}
    return targets, log_k


def _record(cfg: TrainConfig, laws: dict[str, GroupedLaw], n_jobs: int) -> dict[str, Any]:
    """What every weight file of the run records of its data: the fitted laws (JSON), the
    number of cached frames and the data hash."""
    return {
        "laws": {k: law.to_json() for k, law in laws.items()},
        "jobs": n_jobs,
        "data_hash": cfg.data_hash(),
    }


def _networks(
    cfg: TrainConfig, labelled: dict[str, bool], stats: Statistics, device: str
) -> tuple[Nets, torch.optim.Optimizer, torch.optim.Optimizer]:
    """The seeded networks on `device` and the Adam optimisers of the generators and the
    critics."""
    torch.manual_seed(cfg.seed)
    nets = Nets(cfg, labelled)
    set_statistics(nets, stats)
    nets.to(device)
    gen_params = list(nets.g.parameters()) + list(nets.inv.parameters())
    disc_params = list(nets.d_s.parameters()) + list(nets.d_t.parameters())
    opt_g = torch.optim.Adam(gen_params, lr=cfg.lr, betas=cfg.betas)
    opt_d = torch.optim.Adam(disc_params, lr=cfg.lr, betas=cfg.betas)
    return nets, opt_g, opt_d


def _config_id(cfg: TrainConfig) -> str:
    """What a checkpoint must match to resume: the config apart from its length and
    checkpoint spacing (a run can be extended), plus the hash of its data."""
    resumable = {k: v for k, v in cfg.to_dict().items() if k not in ("steps", "checkpoint_every")}
    resumable["data_hash"] = cfg.data_hash()  # checkpoints of other source frames never resume
    return json.dumps(resumable, sort_keys=True, default=str)


def _progress_bar(cfg: TrainConfig, start: int, end: int, progress: bool) -> tqdm[int]:
    """The steps from `start` to `end` with a progress bar over the whole run."""
    return tqdm(
        range(start, end),
        initial=start,
        total=cfg.steps,
        desc=f"train {cfg.name}",
        unit="step",
        disable=not progress,
    )


def _set_learning_rate(optimisers: tuple[torch.optim.Optimizer, ...], lr: float) -> None:
    for opt in optimisers:
        for group in opt.param_groups:
            group["lr"] = lr


def _check_finite(cfg: TrainConfig, step: int, losses: dict[str, float], ckpt_path: Path) -> None:
    """Refuse a diverged step.

    Raises:
        TrainingError: a loss is NaN or infinite.
    """
    if not all(math.isfinite(v) for v in losses.values()):
        raise TrainingError(
            f"{cfg.name}: loss became NaN/inf at step {step} ({losses}); lower lr in the "
            f"config and restart (delete {ckpt_path} to start over)."
        )


def _finish(
    cfg: TrainConfig,
    run: Path,
    nets: Nets,
    selector: Selector,
    meta_at: Callable[[int], ModelMeta],
    steps_done: int,
) -> dict[str, Any]:
    """The run's summary; once every step is done, also writes the weight file: the
    generator that scored best on validation, else (no validation frames) the last one."""
    summary: dict[str, Any] = {
        "run_dir": str(run),
        "steps_done": steps_done,
        "selection": selector.record.get("best"),
    }
    if steps_done < cfg.steps:
        return summary
    weights = cfg.output_path(run)
    best = selector.best_step
    if best is None:  # no validation frames: the last step is the model
        nets.g.cpu()
        save_model(weights, meta_at(steps_done), nets.g)
    else:
        atomic_copy(run / BEST, weights)
    summary["weights"] = str(weights)
    summary["selected_step"] = best if best is not None else steps_done
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
        law_input=cfg.law_input,
        training={
            "config": cfg.to_dict(),
            "steps": step,
            "seed": cfg.seed,
            "final_losses": history[step - 1] if history else {},
            "loss_shares": _loss_shares(cfg, history[max(0, step - 100) : step]),
            "physics_reference": record["laws"],
            "cache_frames": record["jobs"],
            "data_hash": record["data_hash"],
            "materials_held": record["materials_held"],
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
