"""`lads synth`: write a synthetic SemanticKITTI, nuScenes or Voxelscape sequence (no dataset
needed)."""

from __future__ import annotations

from pathlib import Path

import click

from lads.errors import ConfigError, LadsError

# lads.synth.LAYOUTS, without importing numpy
_LAYOUTS = ("semantickitti", "nuscenes", "voxelscape")


@click.command("synth")
@click.option(
    "--sensor",
    default=None,
    help="Sensor profile name or YAML path (see `lads profiles`). Default: hdl64e, "
    "or hdl32e for --layout nuscenes.",
)
@click.option("--frames", type=int, default=20, show_default=True, help="Frames at 10 Hz.")
@click.option(
    "--layout",
    type=click.Choice(_LAYOUTS),
    default="semantickitti",
    show_default=True,
    help="Dataset tree to write.",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Root of the tree (created if missing).",
)
@click.option(
    "--sequence",
    default="00",
    show_default=True,
    help="Sequence folder name (nuscenes: scene-00SS).",
)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
def synth_command(
    sensor: str | None, frames: int, layout: str, out: Path, sequence: str, seed: int
) -> None:
    """Ray-cast a seeded procedural street for SENSOR and write it as a dataset tree."""
    from lads.synth.writer import write_synthetic_dataset

    try:
        summary = write_synthetic_dataset(
            out,
            sensor=sensor,
            frames=frames,
            layout=layout,
            sequence=sequence,
            seed=seed,
            progress=True,
        )
    except ConfigError as err:
        raise click.UsageError(str(err)) from err
    except LadsError as err:
        raise click.ClickException(str(err)) from err
    counts = summary.points_per_frame
    click.echo(
        f"{summary.out_root}: {summary.frames} {summary.layout} frames of sequence {sequence} "
        f"({summary.sensor}, seed {seed}), {min(counts)}-{max(counts)} points per frame, "
        f"{len(summary.files)} files"
    )
