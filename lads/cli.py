"""The `lads` command line.

Exit codes: `lads.exit_codes` (0 success, 1 a result that is not clean, 2 a LadsError, 130 a
build interrupted by Ctrl-C).
"""

from __future__ import annotations

import contextlib
import functools
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from lads.cli_options import (
    SOURCE,
    SOURCE_ROOT,
    jobs_option,
    reader_options,
    seed_option,
    weather_physics_options,
)
from lads.correspondence import POINT_MODES
from lads.errors import LadsError
from lads.exit_codes import EXIT_INCOMPLETE, EXIT_INTERRUPTED, EXIT_LADS_ERROR
from lads.physics.severity import SEVERITIES
from lads.point_format import POINT_FORMATS
from lads.readers import READERS

if TYPE_CHECKING:
    from lads.config import PipelineConfig


def _lads_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except LadsError as err:
            click.echo(f"lads: error: {err}", err=True)
            sys.exit(EXIT_LADS_ERROR)

    return wrapper


class _LazyGroup(click.Group):
    """A click group whose heavier subcommands are imported only when run or listed in help:
    `lads build` starts without loading the training and synthesis modules."""

    LAZY = {
        "synth": ("lads.synth.command", "synth_command", False),
        "weather": ("lads.weather_command", "weather_command", True),
        "suite": ("lads.suite_command", "suite_command", True),
        "verify": ("lads.verify_command", "verify_command", True),
        "diagnose": ("lads.diagnose.command", "diagnose_command", True),
        "train": ("lads.intensity.commands", "train_command", True),
        "eval-intensity": ("lads.intensity.commands", "eval_intensity_command", True),
    }

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted([*super().list_commands(ctx), *self.LAZY])

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.LAZY:
            return super().get_command(ctx, cmd_name)
        import importlib

        module, name, wrap = self.LAZY[cmd_name]
        command = getattr(importlib.import_module(module), name)
        if wrap and not getattr(command, "_lads_wrapped", False):
            command.callback = _lads_errors(command.callback)
            command._lads_wrapped = True  # type: ignore[attr-defined]
        return command


@click.group(cls=_LazyGroup)
@click.version_option(package_name="lads")
def main() -> None:
    """LADS: the same LiDAR scene under another sensor or another weather."""


@main.command()
@click.option(
    "--out", type=click.Path(path_type=Path), default=Path("demo_output"), show_default=True
)
@click.option("--frames", type=click.IntRange(min=1), default=8, show_default=True)
@click.option("--sensor", default="hdl64e", show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--jobs", type=click.IntRange(min=1), default=2, show_default=True)
@_lads_errors
def demo(out: Path, frames: int, sensor: str, seed: int, jobs: int) -> None:
    """Synthesise a sequence, build snow/rain/fog, verify them, draw before/after figures."""
    from lads.demo import main as demo_main

    code = demo_main(
        [
            "--out",
            str(out),
            "--frames",
            str(frames),
            "--sensor",
            sensor,
            "--seed",
            str(seed),
            "--jobs",
            str(jobs),
        ]
    )
    if code:
        sys.exit(EXIT_INCOMPLETE)


@main.command()
@_lads_errors
def profiles() -> None:
    """List the shipped sensor profiles."""
    from lads.sensors.profile import available_profiles, load_profile

    for name in available_profiles():
        p = load_profile(name)
        click.echo(
            f"{p.name:8s} {p.channels:3d} ch  "
            f"{p.vertical_fov_deg[0]:+.1f}..{p.vertical_fov_deg[1]:+.1f} deg  "
            f"{p.min_range_m:g}-{p.max_range_m:g} m  intensity {p.intensity.kind}  {p.description}"
        )


@main.command()
@_lads_errors
def variants() -> None:
    """List the variants of every source and the shipped pipeline each one runs."""
    from lads.config import find_pipeline, pipeline_for, variants_for
    from lads.variant_families import fold_severity

    for source in sorted(READERS):
        shown = set()
        for variant in variants_for(source):
            # The suite's variants: one line per corruption, its severities folded.
            name = fold_severity(variant)
            if name in shown:
                continue
            shown.add(name)
            path = find_pipeline(source, variant)
            stages = ", ".join(s.stage for s in pipeline_for(source, variant).stages)
            click.echo(f"{source:14s} {name:42s} {path.name:24s} {stages}")


@main.command()
@SOURCE
@click.option(
    "--variant",
    help="Variant: snow, rain, fog, wet-ground, intensity-kitti, intensity-nuscenes or "
    "sensor-<profile> (`lads variants` lists them per source with the shipped pipeline each "
    "one runs).",
)
@click.option(
    "--pipeline",
    "pipeline_file",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Use this pipeline YAML instead of --variant.",
)
@SOURCE_ROOT
@click.option(
    "--out",
    "out_root",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Output root (new, or a partial build of the same settings to resume).",
)
@seed_option()
@click.option("--rate-mm-h", type=float, help="Override the rain/snow rate, mm/h.")
@click.option("--visibility-m", type=float, help="Override the fog visibility, m.")
@click.option("--water-film-mm", type=float, help="Override the wet-ground water film, mm.")
@click.option(
    "--severity",
    type=click.Choice(SEVERITIES, case_sensitive=False),
    help="Weather severity preset: sets the rain/snow rate or fog visibility to the preset's "
    "(docs/physics.md, 'Severity presets'); both are recorded.",
)
@weather_physics_options(default_mode=None, default_settings=None)
@click.option(
    "--points",
    type=click.Choice(list(POINT_MODES)),
    help="Point correspondence (docs/output_tree.md).",
)
@click.option("--particle-label", type=int, help="Label of particle returns in physical mode.")
@click.option(
    "--neighbours",
    type=int,
    help="Sensor variants: neighbouring scans in each frame's window (default 10; 0: each "
    "frame from its own scan, no poses needed). docs/transfer.md.",
)
@click.option(
    "--point-format",
    type=click.Choice(POINT_FORMATS),
    help="Sensor variants: write each scan in the source's point record (source, the default) "
    "or in the target sensor's native one (target: e.g. x, y, z, intensity, ring for the "
    "hdl32e), at the source's paths. docs/transfer.md §3.",
)
@click.option(
    "--intensity",
    "intensity_model",
    help="'physics' keeps the physics intensity (drops the learned intensity stage); a shipped "
    "model name or .pt path replaces the pipeline's model.",
)
@click.option(
    "--device",
    type=click.Choice(["cpu", "cuda"]),
    help="Device of the learned intensity stage: cpu (the default, bytes reproducible "
    "everywhere) or cuda (needs a CUDA GPU; a value may differ by one quantisation step).",
)
@click.option(
    "--sequences",
    help="Comma-separated sequences to build (SemanticKITTI, WADS, Voxelscape, RADIATE; the "
    "scene folders of nuscenes-kitti).",
)
@click.option("--version", "nuscenes_version", help="nuScenes table version, e.g. v1.0-trainval.")
@click.option(
    "--sensor",
    "source_sensor",
    help="Sensor profile of the source's scans when it is not the dataset's own: a tree "
    "`--variant sensor-<profile>` built (its run.json names the profile).",
)
@click.option("--include-sweeps", is_flag=True, help="nuScenes: transform sweeps too.")
@jobs_option()
@click.option(
    "--batch",
    type=click.IntRange(min=1),
    help="Frames per task; the learned stage runs them in one forward pass (default: 8 with "
    "--device cuda, else 1). Output bytes do not depend on it.",
)
@click.option("--backend", type=click.Choice(["loky", "dask"]), default="loky", show_default=True)
@click.option("--scheduler", help="Dask scheduler address (with --backend dask).")
@click.option("--fail-fast", is_flag=True, help="Stop at the first bad item.")
@click.option(
    "--wait",
    is_flag=True,
    help="If another lads process is writing --out, wait for it instead of refusing.",
)
@click.option("--limit", type=click.IntRange(min=1), help="Only the first N items (trial runs).")
@click.option(
    "--figures/--no-figures",
    default=True,
    show_default=True,
    help="Draw a before/after preview for the dataset card.",
)
@_lads_errors
def build(**options: Any) -> None:
    """Build a variant tree: one output item per source item, same format and layout."""

    opts = _BuildOptions(**options)
    with _resumable():
        report = _run(opts)
    click.echo(report.summary_text())
    if not report.complete:
        sys.exit(EXIT_INCOMPLETE)


@contextlib.contextmanager
def _resumable() -> Iterator[None]:
    """Ctrl-C (or SIGINT) during a build: say that the finished items are kept and how to
    go on, instead of click's bare "Aborted!"."""
    try:
        yield
    except KeyboardInterrupt:
        click.echo(
            "lads: interrupted; the items built so far are kept: run the same command again "
            "to resume.",
            err=True,
        )
        sys.exit(EXIT_INTERRUPTED)


def _run(opts: _BuildOptions) -> Any:
    from lads.runner import run_build

    return run_build(
        opts.source,
        opts.source_root,
        opts.out_root,
        _build_pipeline(opts),
        seed=opts.seed,
        reader_options=reader_options(
            opts.sequences, opts.nuscenes_version, opts.include_sweeps, opts.source_sensor
        ),
        jobs=opts.jobs,
        backend=opts.backend,
        scheduler=opts.scheduler,
        fail_fast=opts.fail_fast,
        progress=None,
        limit=opts.limit,
        figures=opts.figures,
        wait=opts.wait,
        batch=opts.batch,
    )


@dataclass(frozen=True, slots=True)
class _BuildOptions:
    """The options of `lads build` by parameter name (meanings and units: `lads build --help`)."""

    source: str
    variant: str | None
    pipeline_file: Path | None
    source_root: Path
    out_root: Path
    seed: int
    rate_mm_h: float | None
    visibility_m: float | None
    water_film_mm: float | None
    severity: str | None
    weather_settings: str | None
    detection: str | float | None
    mode: str | None
    neighbours: int | None
    point_format: str | None
    source_sensor: str | None
    points: str | None
    particle_label: int | None
    intensity_model: str | None
    device: str | None
    sequences: str | None
    nuscenes_version: str | None
    include_sweeps: bool
    jobs: int
    batch: int | None
    backend: str
    scheduler: str | None
    fail_fast: bool
    wait: bool
    limit: int | None
    figures: bool


def _build_pipeline(opts: _BuildOptions) -> PipelineConfig:
    """The pipeline of --variant or --pipeline with the command line's overrides applied."""
    from lads.config import load_pipeline, pipeline_for

    if (opts.variant is None) == (opts.pipeline_file is None):
        raise click.UsageError("give exactly one of --variant and --pipeline")
    loaded = (
        load_pipeline(opts.pipeline_file)
        if opts.pipeline_file is not None
        else pipeline_for(opts.source, opts.variant)  # type: ignore[arg-type]
    )
    pipeline = loaded.with_overrides(
        rate_mm_h=opts.rate_mm_h,
        visibility_m=opts.visibility_m,
        water_film_mm=opts.water_film_mm,
        severity=opts.severity,
        mode=opts.mode,
        settings=opts.weather_settings,
        detection=opts.detection,
        points=opts.points,
        particle_label=opts.particle_label,
        intensity=opts.intensity_model,
        neighbours=opts.neighbours,
        point_format=opts.point_format,
    )
    if opts.device is not None:
        pipeline = pipeline.with_overrides(device=opts.device)
    return pipeline


@main.command()
@click.argument("out_root", type=click.Path(exists=True, file_okay=False, path_type=Path))
@_lads_errors
def card(out_root: Path) -> None:
    """Rewrite the dataset card (README.md) of a built tree and its line in SHA256SUMS."""
    from lads.finalise import refresh_card

    click.echo(f"wrote {refresh_card(out_root)}")


if __name__ == "__main__":
    main()
