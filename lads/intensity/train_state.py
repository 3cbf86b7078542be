"""A training run's state on disk: the resumable checkpoint (networks, optimisers, random
generators, loss history) and the loss-curve figure."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lads.errors import TrainingError
from lads.files import atomic_write, atomic_write_figure
from lads.intensity.train_nets import Nets


def save_checkpoint(
    path: Path,
    config_id: str,
    step: int,
    nets: Nets,
    opt_g: Any,
    opt_d: Any,
    rng: np.random.Generator,
    history: list[dict[str, float]],
) -> None:
    """Everything a killed run needs to go on bit for bit, written atomically."""
    blob = {
        "config": config_id,
        "step": step,
        "nets": nets.state_dict(),
        "opt_g": opt_g.state_dict(),
        "opt_d": opt_d.state_dict(),
        "numpy_rng": json.dumps(rng.bit_generator.state),
        "torch_rng": torch.get_rng_state(),
        "history": json.dumps(history),
    }
    buffer = io.BytesIO()
    torch.save(blob, buffer)
    atomic_write(path, buffer.getvalue())


def resume(
    path: Path, config_id: str, nets: Nets, opt_g: Any, opt_d: Any, rng: np.random.Generator
) -> tuple[int, list[dict[str, float]]]:
    """Load a checkpoint into the run's objects; (step reached, loss history).

    Raises:
        TrainingError: a checkpoint of another config, or one that cannot be read.
    """
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
        if blob["config"] != config_id:
            raise TrainingError(
                f"{path}: checkpoint of another config; delete it (or the run folder) to "
                "start over, or restore the config it was made with."
            )
        nets.load_state_dict(blob["nets"])
        opt_g.load_state_dict(blob["opt_g"])
        opt_d.load_state_dict(blob["opt_d"])
        rng.bit_generator.state = json.loads(blob["numpy_rng"])
        torch.set_rng_state(blob["torch_rng"])
        return int(blob["step"]), list(json.loads(blob["history"]))
    except TrainingError:
        raise
    except Exception as exc:
        raise TrainingError(
            f"{path}: cannot resume from this checkpoint ({type(exc).__name__}: {exc}); delete "
            "it to start over."
        ) from None


def write_loss_figure(history: list[dict[str, float]], path: Path, title: str) -> None:
    """Loss curves (moving average over 25 steps) as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not history:
        return
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    steps = np.arange(1, len(history) + 1)
    panels = (
        (axes[0], ("generator", "critic")),
        (axes[1], ("adversarial", "cycle", "physics", "identity", "style")),
    )
    for ax, names in panels:
        for name in names:
            values = np.array([h[name] for h in history])
            if not np.any(values):
                continue
            k = min(25, len(values))
            smooth = np.convolve(values, np.ones(k) / k, mode="valid")
            ax.plot(steps[k - 1 :], smooth, label=name)
        ax.set_xlabel("step")
        ax.set_ylabel("loss (25-step mean)")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"{title}: objectives")
    axes[1].set_title("generator terms (unweighted)")
    fig.tight_layout()
    atomic_write_figure(fig, path, dpi=110)
    plt.close(fig)
