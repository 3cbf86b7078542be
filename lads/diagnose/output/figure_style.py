"""Drawing helpers of the `lads diagnose` figures (lads.diagnose.output.figures): private Agg
figures, fixed margins, tick labels, profiles with their intervals."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lads.diagnose.where.localize import FeatureProfile
from lads.files import atomic_write_figure

DPI = 100
MAX_TICKS = 12


def profile(ax: Any, p: FeatureProfile, colour: str, label: str, shift: float) -> None:
    """A feature profile's mean residual with its interval: a line for ordered features,
    points with error bars (shifted by `shift`) for categories."""
    s = p.intensity
    x = np.arange(len(p.labels), dtype=np.float64)
    ok = np.isfinite(s.mean)
    lo = np.where(np.isfinite(s.mean_low), s.mean_low, s.mean)
    hi = np.where(np.isfinite(s.mean_high), s.mean_high, s.mean)
    if p.ordered:
        ax.plot(x[ok], s.mean[ok], "o-", color=colour, markersize=3, label=label)
        ax.fill_between(x[ok], lo[ok], hi[ok], color=colour, alpha=0.25, linewidth=0)
    else:
        err = np.vstack([np.clip(s.mean - lo, 0, None), np.clip(hi - s.mean, 0, None)])[:, ok]
        ax.errorbar(
            x[ok] + shift,
            s.mean[ok],
            yerr=err,
            fmt="o",
            color=colour,
            markersize=3,
            elinewidth=0.8,
            label=label,
        )


def ticks(ax: Any, labels: Sequence[str], axis: str = "x") -> None:
    """At most MAX_TICKS shortened category labels on an axis."""
    step = max(1, math.ceil(len(labels) / MAX_TICKS))
    pos = np.arange(0, len(labels), step)
    text = [short(labels[i]) for i in pos]
    if axis == "x":
        ax.set_xticks(pos, text, rotation=45, ha="right", fontsize=6)
    else:
        ax.set_yticks(pos, text, fontsize=6)
    ax.tick_params(labelsize=6)


def short(label: str, width: int = 16) -> str:
    """A label cut to `width` characters from its end."""
    return label if len(label) <= width else "..." + label[-(width - 3) :]


def num(value: Any) -> float:
    """float(value), NaN when it is not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def figure(
    size: tuple[float, float], rows: int, cols: int, *, layout: Literal["constrained"] | None = None
) -> tuple[Any, list[Any]]:
    """A private Agg figure (no pyplot state) and its axes, flattened."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, list(axes.reshape(-1))


def cmap(name: str, *, bad: str) -> Any:
    """A named colormap with `bad` for missing cells."""
    import matplotlib

    return matplotlib.colormaps[name].with_extremes(bad=bad)


def save(fig: Any, path: Path, *, margins: bool = True, bottom_in: float = 0.9) -> Path:
    """Write the figure atomically as a PNG; returns the path."""
    # Fixed margins in inches: tight_layout costs about a second per multi-panel figure.
    if margins:
        width, height = fig.get_figwidth(), fig.get_figheight()
        fig.subplots_adjust(
            left=0.75 / width,
            right=1 - 0.2 / width,
            top=1 - 0.65 / height,
            bottom=bottom_in / height,
            wspace=0.35,
            hspace=0.75,
        )
    atomic_write_figure(fig, Path(path), dpi=DPI)
    return Path(path)
