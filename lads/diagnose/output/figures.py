"""PNG figures of `lads diagnose` (docs/diagnose.md §5.6).

Drawn with matplotlib's Agg canvas on private Figures (no pyplot state) and written with
`lads.files.atomic_write_figure`. Residuals are r = ln(I_real + h) - ln(I_sim + h), written
ln(I_real/I_sim) on the axes; every function returns the path it wrote.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.diagnose.data.table import BeamTable
from lads.diagnose.output import figure_style as style
from lads.diagnose.selection.select import Z_ACCEPT
from lads.diagnose.where.binning import RANGE_EDGES_M
from lads.diagnose.where.localize import Localization

MAX_CLASS_PANELS = 6
MAX_HISTOGRAMS = 30
MIN_RATE_ROWS = 20  # a return-rate point needs this many sim beams in its range bin
R_LABEL = "mean ln(I_real/I_sim)"
AXIS_LABELS = {
    "range": "range (m)",
    "cos_incidence": "cos(incidence angle)",
    "class": "class",
    "ring": "laser ring (0 = lowest beam)",
    "azimuth": "azimuth sector (deg)",
    "i_sim_decile": "I_sim decile (stored units)",
    "edge_distance": "distance to a range edge (beams)",
    "ground": "surface",
    "scan": "scan",
}
BEFORE, AFTER = "C0", "C3"


def residual_panels(loc_before: Localization, loc_after: Localization | None, path: Path) -> Path:
    """One panel per feature: binned mean residual with its 95% CI, before (and after) a fit.

    Ordered features are drawn as lines with CI bands, categorical ones as points with
    error bars; bins without rows are left out. The title gives the feature's q-value.

    Args:
        loc_before: the localization of the residual before the fit.
        loc_after: the same after the fit (same table, residual passed to `localize`), or None.
        path: PNG path (folders created, written atomically).

    Returns:
        path.
    """
    names = list(loc_before.features)
    cols = 3
    rows = max(math.ceil(len(names) / cols), 1)
    fig, axes = style.figure((4.6 * cols, 3.3 * rows), rows, cols)
    for ax, name in zip(axes, names, strict=False):
        before = loc_before.features[name]
        style.profile(ax, before, BEFORE, "before", 0.0)
        if loc_after is not None and name in loc_after.features:
            style.profile(ax, loc_after.features[name], AFTER, "after", 0.15)
        ax.axhline(0.0, color="0.3", linewidth=0.8)
        q = before.intensity.q_value
        ax.set_title(
            f"{before.title} (q = {q:.2g})" if math.isfinite(q) else before.title, fontsize=9
        )
        ax.set_xlabel(AXIS_LABELS.get(name, name), fontsize=8)
        ax.set_ylabel(R_LABEL, fontsize=8)
        style.ticks(ax, before.labels)
        if loc_after is not None:
            ax.legend(fontsize=7)
    for ax in axes[len(names) :]:
        ax.set_visible(False)
    after = " before (blue) and after (red) the fit" if loc_after is not None else ""
    fig.suptitle(
        f"binned residual ln(I_real/I_sim) with 95% cluster-bootstrap CIs{after}", fontsize=10
    )
    return style.save(fig, path)


def heatmaps(loc: Localization, path: Path) -> Path:
    """Mean residual over range x cos(theta), ring x range and class x range.

    A diverging colour map centred at 0 (red: real brighter than simulated); cells with
    fewer than 20 rows are grey.

    Args:
        loc: a localization (its `heatmaps`).
        path: PNG path.

    Returns:
        path.
    """
    maps = list(loc.heatmaps.values())
    fig, axes = style.figure(
        (5.4 * max(len(maps), 1) + 1.0, 5.2), 1, max(len(maps), 1), layout="constrained"
    )
    finite = np.concatenate([m.mean[np.isfinite(m.mean)] for m in maps] + [np.zeros(1)])
    vmax = max(float(np.percentile(np.abs(finite), 99)), 1e-3)
    cmap = style.cmap("RdBu_r", bad="0.85")
    image = None
    for ax, m in zip(axes, maps, strict=False):
        image = ax.imshow(
            m.mean,
            aspect="auto",
            origin="lower",
            cmap=cmap,
            vmin=-vmax,
            vmax=vmax,
            interpolation="nearest",
        )
        ax.set_xlabel(AXIS_LABELS.get(m.cols, m.cols), fontsize=8)
        ax.set_ylabel(AXIS_LABELS.get(m.rows, m.rows), fontsize=8)
        ax.set_title(f"{m.rows} x {m.cols}", fontsize=9)
        style.ticks(ax, m.col_labels)
        style.ticks(ax, m.row_labels, axis="y")
    if image is None:
        axes[0].text(0.5, 0.5, "no heatmap data", ha="center", va="center")
    else:
        bar = fig.colorbar(image, ax=list(axes))
        bar.set_label(R_LABEL, fontsize=8)
    fig.suptitle("mean residual ln(I_real/I_sim) by two features (grey: < 20 rows)", fontsize=10)
    return style.save(fig, path, margins=False)


def ring_gains(
    values_by_ring: npt.ArrayLike,
    ci_low: npt.ArrayLike,
    ci_high: npt.ArrayLike,
    path: Path,
    *,
    ylabel: str = "ln g_ring (term of ln I_real - ln I_sim)",
) -> Path:
    """Per-ring gain bars with 95% CI error bars.

    Args:
        values_by_ring: (K,) fitted gain per ring (ln units by default; NaN: not fitted).
        ci_low, ci_high: (K,) CI bounds in the same units.
        path: PNG path.
        ylabel: the values' meaning and units.

    Returns:
        path.
    """
    v, lo, hi = (
        np.asarray(a, dtype=np.float64).reshape(-1) for a in (values_by_ring, ci_low, ci_high)
    )
    fig, axes = style.figure((max(6.0, 0.16 * v.size + 2.0), 3.6), 1, 1)
    ax = axes[0]
    ring = np.arange(v.size)
    err = np.vstack([np.clip(v - lo, 0, None), np.clip(hi - v, 0, None)])
    ax.bar(ring, np.nan_to_num(v), color="C0", width=0.8)
    ax.errorbar(ring, v, yerr=np.nan_to_num(err), fmt="none", ecolor="0.2", linewidth=0.8)
    ax.axhline(0.0, color="0.3", linewidth=0.8)
    ax.set_xlabel("laser ring (0 = lowest beam)", fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.set_title("per-ring gain with 95% CI", fontsize=10)
    ax.tick_params(labelsize=7)
    return style.save(fig, path)


def return_rate(table: BeamTable, predicted_return_prob: npt.ArrayLike | None, path: Path) -> Path:
    """Return rate of simulated beams vs range, per class: real, simulated (1) and fitted.

    Panels for the six most frequent classes among beams the simulation returned (one
    panel of all rows when the table is unlabelled).

    Args:
        table: the beam table.
        predicted_return_prob: (N,) fitted probability that reality returns the beam, or None.
        path: PNG path.

    Returns:
        path.
    """
    fitted = None
    if predicted_return_prob is not None:
        fitted = np.asarray(predicted_return_prob, dtype=np.float64).reshape(-1)
    sim = table.ret_sim
    panels: list[tuple[str, npt.NDArray[np.bool_]]] = []
    labelled = sim & (table.class_id >= 0)
    if labelled.any():
        ids, counts = np.unique(table.class_id[labelled], return_counts=True)
        for cid in ids[np.argsort(-counts, kind="stable")][:MAX_CLASS_PANELS]:
            name = table.class_names.get(int(cid), f"class {cid}")
            panels.append((name, labelled & (table.class_id == cid)))
    else:
        panels.append(("all beams", sim))
    edges = np.asarray(RANGE_EDGES_M)
    centres = np.sqrt(edges[:-1] * edges[1:])
    bins = np.clip(np.searchsorted(edges[1:-1], table.range_m, side="right"), 0, centres.size - 1)
    cols = min(len(panels), 3)
    rows = math.ceil(len(panels) / cols)
    fig, axes = style.figure((4.4 * cols, 3.3 * rows), rows, cols)
    for ax, (name, rows_mask) in zip(axes, panels, strict=False):
        n = np.bincount(bins[rows_mask], minlength=centres.size)
        shown = n >= MIN_RATE_ROWS
        with np.errstate(invalid="ignore", divide="ignore"):
            real = np.bincount(bins[rows_mask], table.ret_real[rows_mask], centres.size) / n
        ax.plot(centres[shown], real[shown], "o-", color="k", label="real")
        ax.plot(centres[shown], np.ones(int(shown.sum())), "--", color="0.5", label="sim")
        if fitted is not None:
            ok = rows_mask & np.isfinite(fitted)
            nf = np.bincount(bins[ok], minlength=centres.size)
            with np.errstate(invalid="ignore", divide="ignore"):
                fit = np.bincount(bins[ok], fitted[ok], centres.size) / nf
            good = nf >= MIN_RATE_ROWS
            ax.plot(centres[good], fit[good], "s-", color=AFTER, label="fitted")
        ax.set_xscale("log")
        ax.set_ylim(0.0, 1.05)
        ax.set_title(f"{name} (N = {int(rows_mask.sum()):,})", fontsize=9)
        ax.set_xlabel("range (m)", fontsize=8)
        ax.set_ylabel("return rate (real returns / sim beams)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=7, loc="lower left")
    for ax in axes[len(panels) :]:
        ax.set_visible(False)
    fig.suptitle("return rate vs range of beams the simulation returned", fontsize=10)
    return style.save(fig, path)


def point_noise(noise: Mapping[str, Any], path: Path) -> Path:
    """Point noise of ln I against range: the model-free scale of neighbour differences per
    range bin (points) and the fitted law (line), as in `point_noise.by_range`.

    Args:
        noise: report.json's `noise_model.point_noise` (with `by_range`).
        path: PNG path.

    Returns:
        path.
    """
    bins = list(noise.get("by_range") or [])
    fig, axes = style.figure((6.0, 3.8), 1, 1)
    ax = axes[0]
    if bins:
        r = np.array([b["range_m"] for b in bins])
        seen = [(b["range_m"], b["sigma_ln_i"]) for b in bins if b["sigma_ln_i"] is not None]
        ax.plot(
            [x for x, _ in seen],
            [y for _, y in seen],
            "o",
            color="k",
            label="neighbour differences (MAD, rounding removed)",
        )
        ax.plot(
            r,
            [b["fitted_sigma_ln_i"] for b in bins],
            "-",
            color=AFTER,
            label="fitted law (Student t, as Gaussian sigma)",
        )
        ax.set_xscale("log")
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, "too few neighbour pairs", ha="center", va="center")
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("range (m)", fontsize=8)
    ax.set_ylabel("point noise sigma of ln I", fontsize=8)
    ax.tick_params(labelsize=7)
    slope = noise.get("range_slope")
    extra = f", range slope {slope:+.2f} per ln R" if slope is not None else ""
    ax.set_title(f"point noise: {noise.get('kind', '?')}{extra}", fontsize=10)
    return style.save(fig, path)


def bootstrap_histograms(samples: Mapping[str, npt.ArrayLike], path: Path) -> Path:
    """One histogram per parameter of its bootstrap replicates, median and 95% interval.

    Args:
        samples: parameter name (units in the name, e.g. "alpha_per_m") -> (B,) replicates;
            a (B, P) array (a per-ring parameter) gives one panel per column. At most 30
            panels are drawn.
        path: PNG path.

    Returns:
        path.
    """
    series: list[tuple[str, npt.NDArray[np.float64]]] = []
    for name, values in samples.items():
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim == 2:
            series += [(f"{name}[{j}]", arr[:, j]) for j in range(arr.shape[1])]
        else:
            series.append((name, arr.reshape(-1)))
    series = series[:MAX_HISTOGRAMS]
    cols = min(max(len(series), 1), 4)
    rows = max(math.ceil(len(series) / cols), 1)
    fig, axes = style.figure((3.6 * cols, 2.8 * rows), rows, cols)
    for ax, (name, arr) in zip(axes, series, strict=False):
        arr = arr[np.isfinite(arr)]
        if arr.size:
            ax.hist(arr, bins=min(30, max(arr.size // 5, 5)), color="C0", alpha=0.8)
            # The report's interval (verdict/intervals.py interval95: order-statistic positions).
            lo, med, hi = np.percentile(arr, [2.5, 50.0, 97.5], method="weibull")
            ax.axvline(med, color="k", linewidth=1.2)
            for x in (lo, hi):
                ax.axvline(x, color="k", linestyle="--", linewidth=0.8)
            ax.set_title(f"{name}: {med:.3g} [{lo:.3g}, {hi:.3g}]", fontsize=8)
        else:
            ax.set_title(f"{name}: no finite replicates", fontsize=8)
        ax.set_xlabel(name, fontsize=8)
        ax.set_ylabel("bootstrap replicates", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes[len(series) :]:
        ax.set_visible(False)
    fig.suptitle(
        "cluster-bootstrap replicates: median (solid) and 95% interval (dashed)", fontsize=10
    )
    return style.save(fig, path)


def selection_trace(steps: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Forward selection: held-out loss reduction per candidate with 1 SE error bars, each
    labelled with its directional score z (the acceptance test: z > select.Z_ACCEPT).

    Args:
        steps: one dict per evaluated candidate: "step" (int), "candidate" (effect ID or
            name), "delta_loss" (held-out loss reduction, positive = better), "se" (its
            cluster SE), "z" (the held-out directional score in SEs), "accepted" (bool).
        path: PNG path.

    Returns:
        path.
    """
    fig, axes = style.figure((max(6.0, 0.45 * len(steps) + 2.5), 4.2), 1, 1)
    ax = axes[0]
    if steps:
        x = np.arange(len(steps))
        delta = np.array([style.num(s.get("delta_loss")) for s in steps])
        se = np.array([style.num(s.get("se")) for s in steps])
        accepted = [bool(s.get("accepted")) for s in steps]
        colours = ["C2" if a else "0.65" for a in accepted]
        ax.bar(
            x,
            np.nan_to_num(delta),
            color=colours,
            edgecolor=["k" if a else "none" for a in accepted],
        )
        ax.errorbar(x, delta, yerr=np.nan_to_num(se), fmt="none", ecolor="0.2", lw=0.8)
        for xi, d, e, s in zip(x, delta, se, steps, strict=True):
            z = style.num(s.get("z"))
            if math.isfinite(z):
                top = (d if math.isfinite(d) else 0.0) + (e if math.isfinite(e) else 0.0)
                ax.annotate(
                    f"z {z:.1f}",
                    (xi, max(top, 0.0)),
                    xytext=(0, 3),
                    textcoords="offset points",
                    fontsize=7,
                    ha="center",
                    va="bottom",
                )
        ax.margins(y=0.15)
        ax.set_xticks(
            x,
            [f"{s.get('step')}: {s.get('candidate')}" for s in steps],
            rotation=60,
            ha="right",
            fontsize=7,
        )
    else:
        ax.text(0.5, 0.5, "no candidates evaluated", ha="center", va="center")
    ax.axhline(0.0, color="0.3", linewidth=0.8)
    ax.set_xlabel("step: candidate effect", fontsize=8)
    ax.set_ylabel("held-out loss reduction (nats per beam)", fontsize=8)
    ax.set_title(
        f"forward selection (green: accepted; error bars 1 SE; z: directional score, "
        f"accepted above {Z_ACCEPT:.0f})",
        fontsize=10,
    )
    return style.save(fig, path)
