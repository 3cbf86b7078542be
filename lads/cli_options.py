"""Command-line options that several `lads` commands share (build, suite), defined once."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from lads.readers import READERS

SOURCE = click.option("--source", required=True, type=click.Choice(sorted(READERS)), help="Reader.")
SOURCE_ROOT = click.option(
    "--in",
    "source_root",
    required=True,
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="Source dataset root.",
)


def seed_option(help_text: str = "Root seed.") -> Any:
    """--seed: an integer >= 0 (every item's randomness derives a numpy SeedSequence from it)."""
    return click.option(
        "--seed", type=click.IntRange(min=0), default=0, show_default=True, help=help_text
    )


def jobs_option(default: int = 1, help_text: str = "Worker processes (loky).") -> Any:
    """--jobs: an integer >= 1."""
    return click.option(
        "--jobs", type=click.IntRange(min=1), default=default, show_default=True, help=help_text
    )


def comma_list(value: str | None) -> list[str] | None:
    """A comma-separated option as a list of its non-empty items (None when not given)."""
    return None if value is None else [v.strip() for v in value.split(",") if v.strip()]


def reader_options(
    sequences: str | None,
    nuscenes_version: str | None,
    include_sweeps: bool = False,
    source_sensor: str | None = None,
) -> dict[str, Any]:
    """The reader options the flags give (`--sequences` is comma-separated)."""
    options: dict[str, Any] = {}
    if sequences:
        options["sequences"] = comma_list(sequences)
    if nuscenes_version:
        options["version"] = nuscenes_version
    if include_sweeps:
        options["include_sweeps"] = True
    if source_sensor:
        options["sensor"] = source_sensor
    return options
