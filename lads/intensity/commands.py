"""`lads train` and `lads eval-intensity`: the CLI side of the intensity models."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click
import numpy as np

from lads.errors import TrainingError
from lads.files import atomic_write, make_folder
from lads.intensity.eval_frames import frames_of
from lads.intensity.train_config import (
    DATA_ROOT_ENV,
    PairSpec,
    TrainConfig,
    load_train_config,
)

if TYPE_CHECKING:  # for annotations only: evaluate_pair imports the evaluation when it runs
    from lads.intensity.evaluate import EvalFrame, EvalResult


def evaluate_pair(
    cfg: TrainConfig,
    pair: PairSpec,
    model_path: str,
    out_dir: Path,
    *,
    split: str = "test",
    figures: bool = True,
) -> dict[str, Any]:
    """Evaluation of one pair on the target's `split` frames ("test", or "validation" while
    choosing): the generator against every baseline fitted on the target's train split, and
    the in-sample bound; writes the report and figures under out_dir/<pair>/ and returns
    the JSON result."""
    from lads.intensity.baselines import InSampleBound, fit_baselines
    from lads.intensity.cache import role_split
    from lads.intensity.eval_metrics import BOUND_PREFIX
    from lads.intensity.eval_report import write_report
    from lads.intensity.evaluate import evaluate

    target = pair.target
    where = f"{cfg.name}: pairs.{pair.key}.target"
    chosen = role_split(target, split, where)
    if not chosen:
        raise TrainingError(
            f"{where}: no {split} frame, so there is nothing to evaluate on; give the target "
            f"a split ({split}: [frame patterns], chosen by place) in the config."
        )
    heldout = frames_of(chosen, cfg.kind)
    names = [f.name for f in heldout]
    reference = frames_of(role_split(target, "train", where), cfg.kind)
    methods = fit_baselines(reference, range_exponent=cfg.range_exponent)
    methods[f"{BOUND_PREFIX}in_sample"] = InSampleBound.of(heldout, cfg.range_exponent)
    methods["generator"] = _generator_method(model_path, pair.key)
    result = evaluate(heldout, methods)
    folder = out_dir / pair.key
    context = {
        "model": model_path,
        "config": cfg.name,
        "pair": pair.key,
        "split": split,
        "frames": names,
        "reference_frames": len(reference),
    }
    write_report(result, folder, title=f"{cfg.name} / {pair.key}: {split} split", context=context)
    if figures:
        _write_figures(result, heldout[0], folder)
    return {"context": context, **result.to_json()}


def _generator_method(model_path: str, key: str) -> Callable[[Any], np.ndarray]:
    """The weight file's generator as an evaluation method: a frame's encoded intensity
    for target `key`."""
    from lads.intensity.checkpoint import resolve_model
    from lads.intensity.predict import predict_points

    model = resolve_model(model_path)

    def generator(frame: Any) -> np.ndarray:
        return predict_points(
            model,
            frame.xyz,
            frame.profile,
            target=key,
            labels=frame.labels,
            label_set=frame.label_set,
            ring=frame.ring,
            particle=frame.particle,
            extinction_per_m=frame.extinction_per_m,
            where=frame.name,
        ).encoded

    return generator


def _write_figures(result: EvalResult, first: EvalFrame, folder: Path) -> None:
    """Range panels (unchanged vs generator) and histograms of the first held-out frame."""
    from lads.intensity import eval_figures

    preds = {name: result.predictions[first.name][name] for name in ("unchanged", "generator")}
    eval_figures.range_panels(first, preds, folder / "range_panels.png")
    eval_figures.histograms(first, result.predictions[first.name], folder / "histograms.png")


_DATA_ROOT_HELP = (
    f"Folder that holds the datasets the config names (semantickitti/, wads/, ...); default "
    f"${DATA_ROOT_ENV}, or the config's own folder for a config given by path."
)


@click.command("train")
@click.argument("config")
@click.option("--data-root", type=click.Path(file_okay=False, path_type=Path), help=_DATA_ROOT_HELP)
@click.option(
    "--run-dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Run folder (cache, checkpoints, loss.png, weights); default runs/<name>.",
)
@click.option(
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Weight file to write; default <run folder>/<name>.pt.",
)
@click.option(
    "--device",
    type=click.Choice(["cpu", "cuda"]),
    default=None,
    help="Default: cuda when present, else cpu.",
)
@click.option("--steps", type=click.IntRange(min=1), help="Override the number of steps.")
@click.option("--jobs", type=click.IntRange(min=1), help="Parallel jobs for the range-image cache.")
def train_command(
    config: str,
    data_root: Path | None,
    run_dir: Path | None,
    output: Path | None,
    device: str | None,
    steps: int | None,
    jobs: int | None,
) -> None:
    """Train an intensity generator from a config: a shipped name (synth-to-kitti,
    synth-to-nuscenes, weather) or a YAML path."""
    from dataclasses import replace

    import torch

    from lads.intensity.train import train

    cfg = load_train_config(config, data_root=data_root)
    if steps is not None:
        cfg = replace(cfg, steps=steps)
    if jobs is not None:
        cfg = replace(cfg, workers=jobs)
    if output is not None:
        cfg = replace(cfg, output=str(output))
    from lads.intensity.checkpoint import checked_device

    dev = checked_device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    summary = train(cfg, run_dir=run_dir, device=dev, progress=True)
    click.echo(json.dumps(summary, indent=2))


@click.command("eval-intensity")
@click.argument("config")
@click.option("--data-root", type=click.Path(file_okay=False, path_type=Path), help=_DATA_ROOT_HELP)
@click.option(
    "--model",
    "model_path",
    help="Weights to evaluate: a .pt path or a shipped name (default: the shipped "
    "model of the config's name, else the config's output).",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("eval-intensity"),
    show_default=True,
)
@click.option(
    "--split",
    type=click.Choice(["test", "validation"]),
    default="test",
    show_default=True,
    help="Which frames to score: test (report once per model) or validation (choose with it).",
)
@click.option("--no-figures", is_flag=True)
def eval_intensity_command(
    config: str,
    data_root: Path | None,
    model_path: str | None,
    out_dir: Path,
    split: str,
    no_figures: bool,
) -> None:
    """Score a generator on the config's test (or validation) frames against the baselines
    fitted on its train frames."""
    from lads.intensity.checkpoint import SHIPPED

    cfg = load_train_config(config, data_root=data_root)
    make_folder(out_dir)  # a bad --out stops here, not after the scoring
    path = model_path or (cfg.name if cfg.name in SHIPPED else str(cfg.output_path()))
    from lads.intensity.cache import role_split

    results = {}
    for pair in cfg.pairs:
        if not role_split(pair.target, split, f"pairs.{pair.key}.target"):
            click.echo(f"{pair.key}: no {split} split in the config; skipped.")
            continue
        results[pair.key] = evaluate_pair(
            cfg, pair, path, out_dir, split=split, figures=not no_figures
        )
    atomic_write(out_dir / "eval.json", json.dumps(results, indent=2, sort_keys=True).encode())
    click.echo(f"wrote {out_dir}/eval.json and per-pair reports")
