"""The `lads` command line.

Exit codes: 0 success; 1 the job ran but its result is not clean (a build with failed
items, a tree that does not verify); 2 a LadsError (bad input, config or paths), with its
message on stderr.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
import numpy as np

from lads.errors import ConfigError, LadsError
from lads.files import atomic_write
from lads.physics.severity import SEVERITIES
from lads.readers import READERS

EXIT_INCOMPLETE = 1
EXIT_LADS_ERROR = 2


def _lads_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except LadsError as err:
            click.echo(f"lads: error: {err}", err=True)
            sys.exit(EXIT_LADS_ERROR)

    return wrapper


def _detection_rule(value: str | None) -> str | float | None:
    """--detection: "sensor", "frame" or a number (a fixed threshold, reflectivity / m^2)."""
    if value is None or value in ("sensor", "frame"):
        return value
    try:
        return float(value)
    except ValueError:
        raise click.BadParameter(
            f"{value!r}: expected sensor, frame or a threshold in reflectivity / m^2"
        ) from None


class _LazyGroup(click.Group):
    """A click group whose heavier subcommands are imported only when run or listed in help:
    `lads build` starts without loading the training and synthesis modules."""

    LAZY = {
        "synth": ("lads.synth.command", "synth_command", False),
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
@click.option("--frames", type=int, default=8, show_default=True)
@click.option("--sensor", default="hdl64e", show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--jobs", type=int, default=2, show_default=True)
@_lads_errors
def demo(out: Path, frames: int, sensor: str, seed: int, jobs: int) -> None:
    """Synthesise a sequence, build snow/rain/fog, verify them, draw before/after figures."""
    from lads.demo import main as demo_main

    code = demo_main(
        ["--out", str(out), "--frames", str(frames), "--sensor", sensor, "--seed", str(seed),
         "--jobs", str(jobs)]
    )  # fmt: skip
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
@click.argument("scan", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("output", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--sensor", required=True, help="Profile name (see `lads profiles`).")
@click.option(
    "--columns",
    type=int,
    default=None,
    help="float32 columns per point (default: 5 if the profile has a ring column, else 4).",
)
@click.option("--rain", "rain_mm_h", type=float, help="Rain rate, mm/h.")
@click.option("--snow", "snow_mm_h", type=float, help="Snowfall rate (water equivalent), mm/h.")
@click.option("--fog", "visibility_m", type=float, help="Fog visibility (MOR), m.")
@click.option(
    "--mode", type=click.Choice(["strongest", "last"]), default="strongest", show_default=True
)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option(
    "--labels",
    "labels_in",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Per-point uint32 labels to carry along.",
)
@click.option(
    "--labels-out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Where to write the carried labels.",
)
@_lads_errors
def weather(
    scan: Path, output: Path, sensor: str, columns: int | None, rain_mm_h: float | None,
    snow_mm_h: float | None, visibility_m: float | None, mode: str, seed: int,
    labels_in: Path | None, labels_out: Path | None,
) -> None:  # fmt: skip
    """Apply one weather to a headerless float32 scan (KITTI .bin, nuScenes .pcd.bin).

    Extra columns (e.g. the nuScenes ring) and labels follow each output point's source beam.
    """
    from lads.physics import weather as wx
    from lads.readers.base import read_labels, read_records
    from lads.sensors.profile import load_profile

    chosen = [v is not None for v in (rain_mm_h, snow_mm_h, visibility_m)]
    if sum(chosen) != 1:
        raise click.UsageError("give exactly one of --rain, --snow, --fog")
    profile = load_profile(sensor)
    ncol = columns or (5 if profile.has_ring_column else 4)
    # A lone file has no reader's layout: the shared record helpers read it (readers/base.py).
    what = f"a scan of {ncol} float32 columns (pass --columns with the file's column count)"
    points = read_records(scan, np.float32, ncol, what)
    rng = np.random.default_rng(seed)
    if rain_mm_h is not None:
        result = wx.rain(
            points[:, :3], points[:, 3], rate_mm_h=rain_mm_h, sensor=profile, rng=rng, mode=mode
        )
    elif snow_mm_h is not None:
        result = wx.snow(
            points[:, :3], points[:, 3], rate_mm_h=snow_mm_h, sensor=profile, rng=rng, mode=mode
        )
    else:
        if visibility_m is None:  # exactly one of the three is given (checked above)
            raise ConfigError("give exactly one of --rain, --snow, --fog")
        result = wx.fog(
            points[:, :3],
            points[:, 3],
            visibility_m=visibility_m,
            sensor=profile,
            rng=rng,
            mode=mode,
        )
    out = points[result.source_index].copy()
    out[:, :3] = result.xyz
    out[:, 3] = result.intensity
    atomic_write(output, out.tobytes())
    if labels_in is not None:
        labels = read_labels(labels_in, np.uint32, points.shape[0], "uint32 labels", scan)
        target = labels_out or output.with_suffix(".label")
        atomic_write(target, labels[result.source_index].tobytes())
    c = result.counts()
    click.echo(
        f"{output}: {out.shape[0]} points (attenuated {c['attenuated']}, particle {c['particle']}, "
        f"lost {c['lost']}); alpha = {result.extinction_per_m:.3e} 1/m"
    )


@main.command()
@_lads_errors
def variants() -> None:
    """List the variants of every source and the shipped pipeline each one runs."""
    from lads.config import find_pipeline, load_pipeline, variants_for

    for source in sorted(READERS):
        for variant in variants_for(source):
            path = find_pipeline(source, variant)
            stages = ", ".join(s.stage for s in load_pipeline(path).stages)
            click.echo(f"{source:14s} {variant:20s} {path.name:24s} {stages}")


@main.command()
@click.option("--source", required=True, type=click.Choice(sorted(READERS)), help="Reader.")
@click.option(
    "--variant",
    help="Variant: snow, rain, fog, intensity-kitti or intensity-nuscenes (`lads variants` "
    "lists them per source with the shipped pipeline each one runs).",
)
@click.option(
    "--pipeline",
    "pipeline_file",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Use this pipeline YAML instead of --variant.",
)
@click.option(
    "--in",
    "source_root",
    required=True,
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="Source dataset root.",
)
@click.option(
    "--out",
    "out_root",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Output root (new, or a partial build of the same settings to resume).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Root seed.")
@click.option("--rate-mm-h", type=float, help="Override the rain/snow rate, mm/h.")
@click.option("--visibility-m", type=float, help="Override the fog visibility, m.")
@click.option("--water-film-mm", type=float, help="Override the wet-ground water film, mm.")
@click.option(
    "--severity", type=click.Choice(SEVERITIES),
    help="Weather severity preset: sets the rain/snow rate or fog visibility to the preset's "
    "(docs/physics.md, 'Severity presets'); both are recorded.",
)  # fmt: skip
@click.option(
    "--weather-settings", type=click.Choice(["lads", "lisa"]),
    help="Physics settings of the weather stage: lads (the default: fitted to real snow, "
    "nothing lost in clear air) or lisa (LISA's published model with its fixed threshold, to "
    "compare; rain and snow).",
)  # fmt: skip
@click.option(
    "--detection", callback=lambda _ctx, _param, value: _detection_rule(value),
    help="Detection rule of the weather stage: sensor (the default: the profile's detection "
    "limit, nothing lost in clear air), frame (the frame's weakest return as threshold) or a "
    "fixed threshold in reflectivity / m^2 (docs/physics.md, 'Detection limits').",
)  # fmt: skip
@click.option(
    "--mode", type=click.Choice(["strongest", "last", "dual"]),
    help="Override the return mode; dual writes a beam's strongest and, where it differs, last "
    "return (physical points only).",
)  # fmt: skip
@click.option(
    "--points",
    type=click.Choice(["physical", "aligned"]),
    help="Point correspondence (docs/output_tree.md).",
)
@click.option("--particle-label", type=int, help="Label of particle returns in physical mode.")
@click.option(
    "--intensity",
    "intensity_model",
    help="'physics' keeps the physics intensity (drops the learned intensity stage); a shipped "
    "model name or .pt path replaces the pipeline's model.",
)
@click.option(
    "--device", type=click.Choice(["cpu", "cuda"]),
    help="Device of the learned intensity stage: cpu (the default, bytes reproducible "
    "everywhere) or cuda (needs a CUDA GPU; a value may differ by one quantisation step).",
)  # fmt: skip
@click.option(
    "--sequences",
    help="Comma-separated sequences to build (SemanticKITTI, WADS, Voxelscape, RADIATE; the "
    "scene folders of nuscenes-kitti).",
)
@click.option("--version", "nuscenes_version", help="nuScenes table version, e.g. v1.0-trainval.")
@click.option("--include-sweeps", is_flag=True, help="nuScenes: transform sweeps too.")
@click.option("--jobs", type=int, default=1, show_default=True, help="Worker processes (loky).")
@click.option(
    "--batch", type=click.IntRange(min=1),
    help="Frames per task; the learned stage runs them in one forward pass (default: 8 with "
    "--device cuda, else 1). Output bytes do not depend on it.",
)  # fmt: skip
@click.option("--backend", type=click.Choice(["loky", "dask"]), default="loky", show_default=True)
@click.option("--scheduler", help="Dask scheduler address (with --backend dask).")
@click.option("--fail-fast", is_flag=True, help="Stop at the first bad item.")
@click.option(
    "--wait", is_flag=True,
    help="If another lads process is writing --out, wait for it instead of refusing.",
)  # fmt: skip
@click.option("--limit", type=int, help="Only the first N items (trial runs).")
@click.option(
    "--figures/--no-figures", default=True, show_default=True,
    help="Draw a before/after preview for the dataset card.",
)  # fmt: skip
@_lads_errors
def build(
    source: str, variant: str | None, pipeline_file: Path | None, source_root: Path, out_root: Path,
    seed: int, rate_mm_h: float | None, visibility_m: float | None,
    water_film_mm: float | None, severity: str | None,
    weather_settings: str | None, detection: str | float | None, mode: str | None,
    points: str | None,
    particle_label: int | None, intensity_model: str | None,
    device: str | None, sequences: str | None, nuscenes_version: str | None,
    include_sweeps: bool, jobs: int, batch: int | None, backend: str, scheduler: str | None,
    fail_fast: bool, wait: bool, limit: int | None, figures: bool,
) -> None:  # fmt: skip
    """Build a variant tree: one output item per source item, same format and layout."""
    from lads.config import find_pipeline, load_pipeline
    from lads.runner import run_build

    if (variant is None) == (pipeline_file is None):
        raise click.UsageError("give exactly one of --variant and --pipeline")
    path = pipeline_file or find_pipeline(source, variant)  # type: ignore[arg-type]
    pipeline = load_pipeline(path).with_overrides(
        rate_mm_h=rate_mm_h, visibility_m=visibility_m, water_film_mm=water_film_mm,
        severity=severity, mode=mode,
        settings=weather_settings, detection=detection, points=points,
        particle_label=particle_label, intensity=intensity_model,
    )  # fmt: skip
    if device is not None:
        pipeline = pipeline.with_overrides(device=device)
    options: dict[str, Any] = {}
    if sequences:
        options["sequences"] = [s.strip() for s in sequences.split(",") if s.strip()]
    if nuscenes_version:
        options["version"] = nuscenes_version
    if include_sweeps:
        options["include_sweeps"] = True
    report = run_build(
        source, source_root, out_root, pipeline, seed=seed, reader_options=options, jobs=jobs,
        backend=backend, scheduler=scheduler, fail_fast=fail_fast, progress=None, limit=limit,
        figures=figures, wait=wait, batch=batch,
    )  # fmt: skip
    click.echo(report.summary_text())
    if not report.complete:
        sys.exit(EXIT_INCOMPLETE)


@main.command()
@click.argument("out_root", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--against",
    "source_root",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="The source tree the output was built from.",
)
@click.option(
    "--regenerate",
    type=int,
    default=0,
    show_default=True,
    help="Rebuild K random items in memory and compare bytes.",
)
@click.option(
    "--inventory", help="Expected release inventory, e.g. semantickitti-00-10 (see manifests/)."
)
@click.option(
    "--seed", type=int, default=0, show_default=True, help="Seed for choosing items to regenerate."
)
@click.option(
    "--json",
    "json_out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also write the report as JSON.",
)
@_lads_errors
def verify(
    out_root: Path, source_root: Path | None, regenerate: int, inventory: str | None, seed: int,
    json_out: Path | None,
) -> None:  # fmt: skip
    """Check a built tree: checksums, manifest, one-to-one layout against the source."""
    from lads.verify import verify_tree

    if regenerate and source_root is None:
        raise click.UsageError("--regenerate needs --against SOURCE")
    report = verify_tree(
        out_root, source_root, regenerate=regenerate, seed=seed, inventory=inventory, progress=None
    )
    if json_out is not None:
        atomic_write(json_out, report.to_json().encode())
    click.echo(report.summary_text())
    if not report.ok:
        sys.exit(EXIT_INCOMPLETE)


@main.command()
@click.argument("out_root", type=click.Path(exists=True, file_okay=False, path_type=Path))
@_lads_errors
def card(out_root: Path) -> None:
    """Rewrite the dataset card (README.md) of a built tree and its line in SHA256SUMS."""
    from lads.finalise import refresh_card

    click.echo(f"wrote {refresh_card(out_root)}")


@main.command()
@click.option(
    "--sim",
    "sim_root",
    required=True,
    type=click.Path(path_type=Path),
    help="Simulated tree (the dataset's own layout).",
)
@click.option(
    "--real",
    "real_root",
    required=True,
    type=click.Path(path_type=Path),
    help="Real tree of the same sensor.",
)
@click.option("--source", required=True, type=click.Choice(["semantickitti", "nuscenes", "wads"]))
@click.option(
    "--paired/--unpaired",
    default=True,
    show_default=True,
    help="Paired: the same scans (same relative paths). Unpaired: other scenes of "
    "the same sensor, compared by feature-conditional distributions only.",
)
@click.option("--out", required=True, type=click.Path(path_type=Path), help="Report folder.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option(
    "--write-corrected",
    "corrected",
    type=click.Path(path_type=Path),
    default=None,
    help="Also write the simulated tree with the fitted effects applied here.",
)
@click.option(
    "--resamples",
    default=None,
    type=int,
    help="Selection reruns on group-bootstrap resamples (stability).",
)
@click.option("--bootstrap", default=None, type=int, help="Bootstrap refits for the CIs.")
@click.option(
    "--jobs",
    default=None,
    type=click.IntRange(min=1),
    help="Processes for the resamples and bootstrap refits [default: 2]; the report does not "
    "depend on it.",
)
@_lads_errors
def diagnose(
    sim_root: Path,
    real_root: Path,
    source: str,
    paired: bool,
    out: Path,
    seed: int,
    corrected: Path | None,
    resamples: int | None,
    bootstrap: int | None,
    jobs: int | None,
) -> None:
    """Locate where simulation and reality differ, name and fit the missing physics."""
    from lads.diagnose.run import diagnose as run_diagnose
    from lads.diagnose.verdict.analysis import Settings

    settings = Settings()
    if resamples is not None:
        settings = dataclasses.replace(settings, resamples=resamples)
    if bootstrap is not None:
        settings = dataclasses.replace(settings, bootstrap=bootstrap)
    if jobs is not None:
        settings = dataclasses.replace(settings, jobs=jobs)
    doc = run_diagnose(
        sim_root,
        real_root,
        source,
        out,
        paired=paired,
        seed=seed,
        write_corrected_to=corrected,
        settings=settings,
        progress=True,
    )
    names = ", ".join(f"{e['id']} {e['key']}" for e in doc["effects"]) or "none"
    click.echo(f"verdict: {doc['verdict']}; effects: {names}; report: {out / 'report.md'}")


if __name__ == "__main__":
    main()
