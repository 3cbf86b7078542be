"""`lads weather SCAN OUTPUT`: one weather on one headerless float32 scan file (no tree)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.files import atomic_write

if TYPE_CHECKING:  # the command imports the physics only when it runs (start-up time)
    from lads.physics.result import WeatherResult
    from lads.sensors.profile import SensorProfile


@click.command("weather")
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
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
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
def weather_command(
    scan: Path,
    output: Path,
    sensor: str,
    columns: int | None,
    rain_mm_h: float | None,
    snow_mm_h: float | None,
    visibility_m: float | None,
    mode: str,
    seed: int,
    labels_in: Path | None,
    labels_out: Path | None,
) -> None:
    """Apply one weather to a headerless float32 scan (KITTI .bin, nuScenes .pcd.bin).

    Extra columns (e.g. the nuScenes ring) and labels follow each output point's source beam.
    """
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
    result = _apply_weather(points, profile, rng, rain_mm_h, snow_mm_h, visibility_m, mode)
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


def _apply_weather(
    points: npt.NDArray[np.float32],
    profile: SensorProfile,
    rng: np.random.Generator,
    rain_mm_h: float | None,
    snow_mm_h: float | None,
    visibility_m: float | None,
    mode: str,
) -> WeatherResult:
    """The one weather given (rain or snow in mm/h, fog by visibility in m) on `points`
    (N, C) float32: x, y, z in m, then the intensity."""
    from lads.physics import weather as wx

    if rain_mm_h is not None:
        return wx.rain(
            points[:, :3], points[:, 3], rate_mm_h=rain_mm_h, sensor=profile, rng=rng, mode=mode
        )
    if snow_mm_h is not None:
        return wx.snow(
            points[:, :3], points[:, 3], rate_mm_h=snow_mm_h, sensor=profile, rng=rng, mode=mode
        )
    if visibility_m is None:  # exactly one of the three is given (checked by the command)
        raise ConfigError("give exactly one of --rain, --snow, --fog")
    return wx.fog(
        points[:, :3],
        points[:, 3],
        visibility_m=visibility_m,
        sensor=profile,
        rng=rng,
        mode=mode,
    )
