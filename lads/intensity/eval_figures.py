"""PNG figures of an intensity evaluation: range-image panels and intensity histograms.

Drawn with matplotlib's Agg canvas on a private Figure (no pyplot state, so it is safe next
to other plotting code), and written atomically. Values are in the frame's intensity
encoding, the units a user of the dataset sees.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import InputDataError
from lads.files import atomic_write_figure
from lads.intensity.evaluate import EvalFrame, class_ids, unchanged_intensity
from lads.physics.materials import class_materials
from lads.physics.projection import project
from lads.sensors.profile import SensorProfile

PANEL_WIDTH_IN = 16.0
# A 64 x 2048 image drawn at its own aspect would be 0.5 in tall; rows are stretched so
# single beams stay visible.
PANEL_HEIGHT_IN = 1.35
AXES_WIDTH_FRACTION = 0.89
MAX_HISTOGRAM_BINS = 256
MAX_CLASS_PANELS = 6
DPI = 100
REAL = "real"
UNCHANGED = "unchanged"
PANEL_TITLES = {
    UNCHANGED: "unchanged: physics input rho cos(theta), as a simulator stores it",
    REAL: "real (measured)",
}


def range_panels(frame: EvalFrame, predictions: Mapping[str, npt.ArrayLike], out: Path) -> Path:
    """Stacked range images of the pixel owners' intensity: methods, then the real one.

    One panel per entry of `predictions` (order kept, "unchanged" first; it is computed
    from the frame when absent, so the physics input is always shown) and the measured
    intensity last, all on one colour scale (0 to the 99.5th percentile of the shown
    values). Rows are channels (top = highest), columns azimuth bins; empty pixels white.

    Args:
        frame: the held-out frame (geometry, ring, profile, real intensity).
        predictions: method -> (N,) intensity in the frame's encoding.
        out: PNG path (folders created, written atomically).

    Returns:
        out.

    Raises:
        InputDataError: a prediction without one value per point.
    """
    from matplotlib.figure import Figure

    shown = _with_unchanged(frame, predictions)
    shown[REAL] = frame.intensity
    image = project(frame.xyz, frame.profile, channel=frame.ring)
    grids, vmax = _owner_grids(frame, shown, image.index)

    # About one screen pixel per azimuth column, so nearest-neighbour drawing drops none.
    width_in = max(PANEL_WIDTH_IN, image.index.shape[1] / DPI / AXES_WIDTH_FRACTION)
    fig = Figure(figsize=(width_in, PANEL_HEIGHT_IN * len(grids) + 0.9), dpi=DPI)
    _agg(fig)
    axes = fig.subplots(len(grids), 1, sharex=True, squeeze=False)[:, 0]
    cmap = _cmap("viridis")
    drawn = []
    for ax, (name, grid) in zip(axes, grids.items(), strict=True):
        drawn.append(
            ax.imshow(grid, aspect="auto", interpolation="nearest", cmap=cmap, vmin=0.0, vmax=vmax)
        )
        ax.set_title(PANEL_TITLES.get(name, name), fontsize=9, loc="left")
        ax.set_ylabel("row", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[-1].set_xlabel("azimuth column", fontsize=8)
    fig.suptitle(
        f"{frame.name}: intensity of the pixel owners ({frame.profile.name} encoding, "
        f"{image.index.shape[0]} x {image.index.shape[1]}, empty pixels white)",
        fontsize=10,
    )
    margin = 0.45 / fig.get_figheight()  # 0.45 in above and below the panels
    right = 0.04 + AXES_WIDTH_FRACTION
    fig.subplots_adjust(left=0.04, right=right, top=1 - margin, bottom=margin, hspace=0.45)
    colour_ax = fig.add_axes((right + 0.01, 0.15, 0.008, 0.7))
    bar = fig.colorbar(drawn[-1], cax=colour_ax)
    bar.set_label(f"intensity ({frame.profile.name} encoding)", fontsize=8)
    bar.ax.tick_params(labelsize=7)
    _save(fig, out)
    return out


def _owner_grids(
    frame: EvalFrame, shown: Mapping[str, npt.NDArray[Any]], index: npt.NDArray[np.int64]
) -> tuple[dict[str, npt.NDArray[np.float32]], float]:
    """Per method, the (H, W) float32 image of the pixel owners' values (NaN where empty),
    and the top of the shared colour scale; `index` is the owner per pixel (-1: none)."""
    owned = index >= 0
    grids = {}
    for name, values in shown.items():
        grid = np.full(index.shape, np.nan, dtype=np.float32)
        grid[owned] = values[index[owned]]
        grids[name] = grid
    pooled = np.concatenate([g[owned] for g in grids.values()])
    # The 99.5th percentile, not the maximum, so a few retro-reflector returns do not
    # squeeze everything else into the bottom of the scale.
    vmax = max(
        float(np.percentile(pooled, 99.5)) if pooled.size else 0.0, frame.profile.intensity.step
    )
    return grids, vmax


def histograms(
    real: EvalFrame | npt.ArrayLike,
    predictions: Mapping[str, npt.ArrayLike],
    out: Path,
    *,
    classes: npt.ArrayLike | None = None,
    class_names: Mapping[Any, str] | Sequence[str] | None = None,
    profile: SensorProfile | None = None,
    title: str | None = None,
) -> Path:
    """Overlaid intensity histograms (log counts) of the real values and every method.

    The top panel holds all points; below it, small multiples for up to the six most
    frequent classes (when classes are known).

    Args:
        real: a held-out frame (its intensity, labels and profile are used) or (M,) real
            values, e.g. `EvalResult.pooled_values()[0]`.
        predictions: method -> (M,) values in the same encoding.
        out: PNG path.
        classes: (M,) class key per point (ignored when `real` is a frame).
        class_names: class key -> display name, or a sequence indexed by integer keys
            (`EvalResult.class_names` for `pooled_values()`); default str(key).
        profile: gives the bins (one per quantisation step, merged to <= 256) and units.
        title: figure title.

    Returns:
        out.

    Raises:
        InputDataError: arrays of different lengths.
    """
    from matplotlib.figure import Figure

    if isinstance(real, EvalFrame):
        frame = real
        values = frame.intensity
        profile = frame.profile
        title = title or f"{frame.name}: intensity histograms"
        classes, class_names = _frame_classes(frame)
    else:
        values = np.asarray(real, dtype=np.float32).reshape(-1)
    preds, cls = _same_points(values, predictions, classes)
    bins = _bins(profile, values, preds)
    unit = f"intensity ({profile.name} encoding)" if profile else "intensity (encoding units)"

    top_classes = _top_classes(cls)
    class_rows = math.ceil(len(top_classes) / 3)
    fig = Figure(figsize=(12.0, 4.2 + 2.8 * class_rows), dpi=DPI)
    _agg(fig)
    grid = fig.add_gridspec(1 + class_rows, 3, height_ratios=(1.6,) + (1.0,) * class_rows)
    _all_points_panel(fig.add_subplot(grid[0, :]), values, preds, bins, unit)
    names = dict(enumerate(class_names)) if isinstance(class_names, Sequence) else class_names
    for i, key in enumerate(top_classes):
        ax = fig.add_subplot(grid[1 + i // 3, i % 3])
        _class_panel(ax, key, names or {}, cls == key, values, preds, bins, unit)
    fig.suptitle(title or "intensity histograms: real vs methods", fontsize=10)
    _fixed_margins(fig)
    _save(fig, out)
    return out


def _top_classes(cls: npt.NDArray[Any] | None) -> list[Any]:
    """The keys of the (up to MAX_CLASS_PANELS) most frequent classes, commonest first."""
    top_classes: list[Any] = []
    if cls is not None:
        keys, counts = np.unique(cls, return_counts=True)
        top_classes = list(keys[np.argsort(-counts, kind="stable")][:MAX_CLASS_PANELS])
    return top_classes


def _all_points_panel(
    ax: Any,
    values: npt.NDArray[np.float32],
    preds: dict[str, npt.NDArray[np.float32]],
    bins: npt.NDArray[np.float64],
    unit: str,
) -> None:
    """Draw the top panel: the real values and every method over all points, with legend."""
    _overlay(ax, values, preds, bins, legend=True)
    ax.set_title(f"all points (N = {values.size:,})", fontsize=9)
    ax.set_xlabel(unit, fontsize=8)
    ax.set_ylabel("points (log scale)", fontsize=8)


def _fixed_margins(fig: Any) -> None:
    """Set the histogram figure's fixed margins: 0.75 in above the panels, 0.5 in below."""
    # Fixed margins: tight_layout would cost a second measuring log-axis tick labels.
    height = fig.get_figheight()
    fig.subplots_adjust(
        left=0.07, right=0.98, top=1 - 0.75 / height, bottom=0.5 / height, hspace=0.55, wspace=0.28
    )


def _same_points(
    values: npt.NDArray[np.float32],
    predictions: Mapping[str, npt.ArrayLike],
    classes: npt.ArrayLike | None,
) -> tuple[dict[str, npt.NDArray[np.float32]], npt.NDArray[Any] | None]:
    """The (M,) float32 predictions by method and the (M,) class keys (or None), checked to
    be one per real value.

    Raises:
        InputDataError: arrays of different lengths.
    """
    preds = {name: np.asarray(v, dtype=np.float32).reshape(-1) for name, v in predictions.items()}
    for name, v in preds.items():
        if v.shape != values.shape:
            raise InputDataError(
                f"histograms: prediction '{name}' has {v.size} values, the real data "
                f"{values.size}; pass values of the same points."
            )
    cls = None if classes is None else np.asarray(classes).reshape(-1)
    if cls is not None and cls.shape != values.shape:
        raise InputDataError(
            f"histograms: {cls.size} class keys for {values.size} values; one per point."
        )
    return preds, cls


def _class_panel(
    ax: Any,
    key: Any,
    names: Mapping[Any, str],
    members: npt.NDArray[np.bool_],
    values: npt.NDArray[np.float32],
    preds: dict[str, npt.NDArray[np.float32]],
    bins: npt.NDArray[np.float64],
    unit: str,
) -> None:
    """One class's small histogram panel: the real values and every method on `members`."""
    _overlay(ax, values[members], {n: v[members] for n, v in preds.items()}, bins)
    ax.set_title(f"{names.get(key, str(key))} (N = {int(members.sum()):,})", fontsize=8)
    ax.set_xlabel(unit, fontsize=7)
    ax.set_ylabel("points (log)", fontsize=7)


def _with_unchanged(
    frame: EvalFrame, predictions: Mapping[str, npt.ArrayLike]
) -> dict[str, npt.NDArray[np.float32]]:
    shown = {
        UNCHANGED: np.asarray(predictions[UNCHANGED])
        if UNCHANGED in predictions
        else unchanged_intensity(frame)
    }
    shown.update({k: np.asarray(v) for k, v in predictions.items() if k != UNCHANGED})
    for name, values in shown.items():
        if values.shape != (frame.n_points,):
            raise InputDataError(
                f"range_panels: prediction '{name}' has shape {values.shape} for frame "
                f"'{frame.name}', expected ({frame.n_points},)."
            )
    return {k: v.astype(np.float32, copy=False) for k, v in shown.items()}


def _frame_classes(frame: EvalFrame) -> tuple[npt.NDArray[Any] | None, dict[Any, str] | None]:
    if frame.labels is None or frame.label_set is None:
        return None, None
    names = {cid: name for cid, (name, _) in class_materials(frame.label_set).items()}
    return class_ids(frame.labels, frame.label_set), names


def _bins(
    profile: SensorProfile | None,
    real: npt.NDArray[np.float32],
    preds: Mapping[str, npt.NDArray[np.float32]],
) -> npt.NDArray[np.float64]:
    if profile is not None:
        enc = profile.intensity
        levels = int(math.floor(enc.max_value / enc.step + 1e-9)) + 1
        # Whole quantisation steps per bin, so no bin catches one level more than its
        # neighbours (which would draw a comb).
        stride = math.ceil(levels / MAX_HISTOGRAM_BINS)
        return (np.arange(0, levels + stride, stride) - 0.5) * enc.step
    top = max([float(real.max(initial=0.0))] + [float(v.max(initial=0.0)) for v in preds.values()])
    return np.linspace(0.0, top if top > 0 else 1.0, 101)


def _overlay(
    ax: Any,
    real: npt.NDArray[np.float32],
    preds: Mapping[str, npt.NDArray[np.float32]],
    bins: npt.NDArray[np.float64],
    *,
    legend: bool = False,
) -> None:
    # Counts as stairs: one artist per series instead of one patch per bin.
    ax.stairs(np.histogram(real, bins)[0], bins, fill=True, color="0.75", label=REAL)
    for name, values in preds.items():
        ax.stairs(np.histogram(values, bins)[0], bins, linewidth=1.2, label=name)
    ax.set_yscale("log")
    ax.tick_params(labelsize=7)
    if legend:
        ax.legend(fontsize=8, ncol=min(len(preds) + 1, 5))


def _cmap(name: str) -> Any:
    import matplotlib

    return matplotlib.colormaps[name].with_extremes(bad="white")


def _agg(fig: Any) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)


def _save(fig: Any, out: Path) -> None:
    atomic_write_figure(fig, Path(out), dpi=DPI)
