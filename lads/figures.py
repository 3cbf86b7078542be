"""Before/after figures of built variants: bird's-eye view, range image, intensity histogram.

Used by `make demo`, dataset cards and the docs. Figures are drawn from files on disk (the
source scan, the variant scan and its provenance), so they show what a user downloads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from lads import provenance
from lads.files import atomic_write_figure
from lads.physics.projection import project
from lads.physics.result import Outcome
from lads.sensors.profile import load_profile

OUTCOME_STYLE = {
    Outcome.KEPT: ("#4a4a4a", "kept"),
    Outcome.ATTENUATED: ("#2f7ed8", "attenuated"),
    Outcome.PARTICLE: ("#e8112d", "particle return"),
    Outcome.LOST: ("#f5a623", "lost (aligned: at origin)"),
    Outcome.RESAMPLED: ("#2a9d4a", "resampled (another sensor's beam)"),
    Outcome.DISPLACED: ("#8e44ad", "displaced (motion distortion)"),
}
BEV_PIXELS = 400  # cells per side of the bird's-eye raster (0.2 m at the default 40 m)


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> None:
    atomic_write_figure(fig, path, dpi=100)
    _plt().close(fig)


def _scan(path: Path, columns: int) -> npt.NDArray[np.float32]:
    return np.fromfile(path, dtype="<f4").reshape(-1, columns)


def _range_image(xyz: npt.NDArray[np.float32], values: npt.NDArray[Any], sensor: str) -> Any:
    profile = load_profile(sensor)
    image = project(xyz, profile)
    grid = np.full(image.index.shape, np.nan, dtype=np.float32)
    owned = image.mask
    grid[owned] = values[image.index[owned]]
    return grid


def _shown(pts: npt.NDArray[np.float32], sensor: str, as_reflectivity: bool) -> Any:
    """The intensity column of a scan, or its reflectivity in the sensor's encoding."""
    if not as_reflectivity:
        return pts[:, 3]
    return load_profile(sensor).intensity.to_reflectivity(pts[:, 3])


def _bev_raster(
    xy: npt.NDArray[np.float32], outcome: npt.NDArray[np.uint8], extent_m: float
) -> npt.NDArray[np.float32]:
    """(BEV_PIXELS, BEV_PIXELS, 4) RGBA bird's-eye view: each cell takes the colour of the
    highest outcome code among its points (particles and lost on top), white when empty.
    A raster, because a scatter of 10^5 points per panel took seconds to draw."""
    from matplotlib.colors import to_rgba_array

    palette = to_rgba_array([OUTCOME_STYLE[o][0] for o in Outcome]).astype(np.float32)
    cell = np.floor((xy + extent_m) / (2.0 * extent_m) * BEV_PIXELS).astype(np.int64)
    inside = np.all((cell >= 0) & (cell < BEV_PIXELS), axis=1)
    top = np.full((BEV_PIXELS, BEV_PIXELS), -1, dtype=np.int64)
    np.maximum.at(top, (cell[inside, 1], cell[inside, 0]), outcome[inside].astype(np.int64))
    image = np.ones((BEV_PIXELS, BEV_PIXELS, 4), dtype=np.float32)
    image[top >= 0] = palette[top[top >= 0]]
    return image


def variant_figure(
    source_root: Path,
    variants: dict[str, Path],
    relpath: str,
    path: Path,
    *,
    sensor: str,
    columns: int = 4,
    extent_m: float = 40.0,
    variant_sensor: str | None = None,
    variant_columns: int | None = None,
) -> Path:
    """One row per tree (source first, then each variant): BEV coloured by outcome and a
    range image of intensity; a last panel overlays the intensity histograms.

    Args:
        source_root: the source tree; variants: name -> built tree.
        relpath: the scan to show (same relative path in every tree).
        sensor: profile used for the range-image projection; variant_sensor: the
            variants' profile when it differs (a sensor transfer).
        columns: float32 columns per point in the source's scan file; variant_columns: in
            the variants' when it differs (a transfer written in the target's record).
    """
    plt = _plt()
    rows = 1 + len(variants)
    fig = plt.figure(figsize=(16, 3.2 * rows))
    grid = fig.add_gridspec(rows, 3, width_ratios=(1.0, 3.2, 1.3))
    src = _scan(source_root / relpath, columns)
    trees = [("source", src, np.full(src.shape[0], Outcome.KEPT, np.uint8), sensor)]
    for name, root in variants.items():
        pts = _scan(root / relpath, variant_columns or columns)
        _, outcome, _ = provenance.read_item(root, relpath)
        trees.append((name, pts, outcome, variant_sensor or sensor))
    hist_ax = fig.add_subplot(grid[:, 2])
    # Trees of two sensors store intensity in two encodings: compare their reflectivity.
    as_refl = variant_sensor not in (None, sensor)
    what = "reflectivity" if as_refl else "stored intensity"
    bins = np.linspace(0.0, float(max(_shown(src, sensor, as_refl).max(), 1e-3)), 60)
    for r, tree in enumerate(trees):
        _tree_row(fig, grid, r, tree, hist_ax, bins, as_refl, extent_m)
    hist_ax.set_yscale("log")
    hist_ax.set_xlabel(what)
    hist_ax.set_title(f"{what} histograms", fontsize=9)
    hist_ax.legend(fontsize=7)
    handles = [
        plt.Line2D([], [], marker="o", ls="", color=c, label=label)
        for c, label in OUTCOME_STYLE.values()
    ]
    fig.legend(handles=handles, loc="lower left", fontsize=7, ncol=4)
    # Fixed margins: tight_layout measured every tick label and took longer than the plot.
    fig.subplots_adjust(
        left=0.04,
        right=0.98,
        bottom=0.05 + 0.1 / rows,
        top=1 - 0.16 / rows,
        wspace=0.18,
        hspace=0.45,
    )
    _save(fig, path)
    return path


def _tree_row(
    fig: Any,
    grid: Any,
    r: int,
    tree: tuple[str, Any, Any, str],
    hist_ax: Any,
    bins: npt.NDArray[np.float64],
    as_refl: bool,
    extent_m: float,
) -> None:
    """Row `r` of `variant_figure`: the tree's BEV and range image, and its histogram."""
    name, pts, outcome, tree_sensor = tree
    what = "reflectivity" if as_refl else "stored intensity"
    bev = fig.add_subplot(grid[r, 0])
    box = (-extent_m, extent_m, -extent_m, extent_m)
    bev.imshow(
        _bev_raster(pts[:, :2], outcome, extent_m),
        origin="lower",
        extent=box,
        interpolation="nearest",
    )
    bev.set(xlim=(-extent_m, extent_m), ylim=(-extent_m, extent_m), aspect="equal")
    counts = np.bincount(outcome, minlength=len(Outcome))
    bev.set_title(f"{name}\n{pts.shape[0]:,} pts · particle {counts[2]:,}", fontsize=9)
    bev.tick_params(labelsize=7)
    keep = outcome != Outcome.LOST
    img = fig.add_subplot(grid[r, 1])
    shown = img.imshow(
        _range_image(pts[keep, :3], _shown(pts[keep], tree_sensor, as_refl), tree_sensor),
        aspect="auto",
        cmap="viridis",
        interpolation="nearest",
        vmin=0.0,
        vmax=bins[-1],
    )
    img.set_title(f"{name}: {what} range image (rows = channels)", fontsize=9)
    img.tick_params(labelsize=7)
    fig.colorbar(shown, ax=img, fraction=0.02)
    hist_ax.hist(
        _shown(pts[keep], tree_sensor, as_refl),
        bins=bins,
        histtype="step",
        density=True,
        label=name,
    )


def correspondence_figure(path: Path) -> Path:
    """Diagram of the two point-correspondence modes (docs/output_tree.md)."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    outcomes = np.array([0, 0, 1, 3, 0, 2, 0, 3, 1, 0], dtype=np.uint8)
    n = outcomes.size
    titles = ("source scan: N = 10 points, labels L0..L9",
              "--points physical: lost removed, particle relabelled",
              "--points aligned: N and order kept, labels reused")  # fmt: skip
    for ax, title in zip(axes, titles, strict=True):
        ax.set_title(title, fontsize=9)
        ax.set_xlim(-0.5, 3.5)
        ax.set_ylim(-0.5, n - 0.5)
        ax.invert_yaxis()
        ax.axis("off")
    for i in range(n):
        axes[0].text(0, i, f"p{i}", ha="center", va="center")
        axes[0].text(1.5, i, f"L{i}", ha="center", va="center")
    row = 0
    for i, o in enumerate(outcomes):
        colour, name = OUTCOME_STYLE[Outcome(int(o))]
        label = "L_particle" if o == Outcome.PARTICLE else f"L{i}"
        axes[2].text(
            0,
            i,
            "(0,0,0), I=0" if o == Outcome.LOST else f"p{i}'",
            ha="center",
            va="center",
            color=colour,
        )
        axes[2].text(1.5, i, f"L{i}", ha="center", va="center")
        axes[2].text(2.9, i, name, ha="center", va="center", color=colour, fontsize=7)
        if o == Outcome.LOST:
            continue
        axes[1].text(0, row, f"p{i}'", ha="center", va="center", color=colour)
        axes[1].text(1.5, row, label, ha="center", va="center")
        axes[1].text(
            2.9, row, f"source_index {i}", ha="center", va="center", color=colour, fontsize=7
        )
        row += 1
    fig.tight_layout()
    _save(fig, path)
    return path


def main(argv: list[str] | None = None) -> int:
    """`python -m lads.figures [DIR]`: draw the documentation figures into DIR (docs)."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m lads.figures", description="Draw the documentation figures."
    )
    parser.add_argument("folder", nargs="?", default="docs", type=Path)
    args = parser.parse_args(argv)
    correspondence_figure(args.folder / "point_correspondence.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
