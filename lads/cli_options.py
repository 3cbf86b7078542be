"""Command-line options that several `lads` commands share (build, suite, weather), defined
once."""

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


# The weather stage's return modes and physics settings (`lads.stage_params.RETURN_MODES`,
# `lads.physics.weather.SETTINGS`; a unit test keeps them equal): spelled out here so that
# the command line starts without importing the physics.
RETURN_MODES = ("strongest", "last", "dual")
WEATHER_SETTINGS = ("lads", "lisa")


def detection_rule(value: str | None) -> str | float | None:
    """--detection: "sensor", "frame" or a number (a fixed threshold, reflectivity / m^2)."""
    if value is None or value in ("sensor", "frame"):
        return value
    try:
        return float(value)
    except ValueError:
        raise click.BadParameter(
            f"{value!r}: expected sensor, frame or a threshold in reflectivity / m^2"
        ) from None


def _choice(name: str, choices: tuple[str, ...], default: str | None, help_text: str) -> Any:
    """A click option taking one of `choices`, its default shown when it has one."""
    return click.option(
        name,
        type=click.Choice(choices),
        default=default,
        show_default=default is not None,
        help=help_text,
    )


def weather_physics_options(default_mode: str | None, default_settings: str | None) -> Any:
    """--mode, --weather-settings and --detection of a weather stage (None: the pipeline's)."""
    options = [
        _choice(
            "--mode",
            RETURN_MODES,
            default_mode,
            "Return mode: dual writes a beam's strongest and, where it differs, last return, "
            "two points on one ray (in a build: physical points only).",
        ),
        _choice(
            "--weather-settings",
            WEATHER_SETTINGS,
            default_settings,
            "Physics settings of the weather: lads (fitted to real snow, nothing lost in clear "
            "air) or lisa (LISA's published model with its fixed threshold, to compare; rain "
            "and snow).",
        ),
        click.option(
            "--detection",
            callback=lambda _ctx, _param, value: detection_rule(value),
            help="Detection rule: sensor (the default for lads: the profile's detection limit, "
            "nothing lost in clear air), frame (the frame's weakest return as threshold) or a "
            "fixed threshold in reflectivity / m^2 (docs/physics.md, 'Detection limits').",
        ),
    ]

    def apply(func: Any) -> Any:
        for option in reversed(options):
            func = option(func)
        return func

    return apply


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
