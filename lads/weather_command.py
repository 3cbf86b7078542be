"""`lads weather SCAN OUTPUT`: one weather on one headerless float32 scan file (no tree).

It runs the build's own weather stage (`lads.stages.weather.WeatherStage`), with the same
parameter checks, severity presets, physics settings and detection rules.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import click
import numpy as np
import numpy.typing as npt

from lads.cli_options import seed_option, weather_physics_options
from lads.errors import ConfigError
from lads.files import atomic_write
from lads.physics.severity import SEVERITIES
from lads.readers import READERS, reader_class

if TYPE_CHECKING:  # the command imports the physics only when it runs (start-up time)
    from lads.physics.result import WeatherResult
    from lads.stages.weather import WeatherStage

# Label files the command reads, told apart by their size: SemanticKITTI-style uint32
# (class in the low 16 bits, instance above) and nuScenes lidarseg uint8.
LABEL_DTYPES = (np.dtype("<u4"), np.dtype("u1"))
# Scans stored as text (RADIATE's .csv): a reader's format, not a headerless record.
TEXT_SUFFIXES = (".csv", ".txt")


def _datasets_particle_labels() -> str:
    """The readers' own particle labels, e.g. "semantickitti 1, wads 110"."""
    return ", ".join(f"{r} {reader_class(r).particle_label}" for r in sorted(READERS))


class _Strength(click.ParamType):
    """A rate (mm/h) or visibility (m) as a number, or a severity preset's name."""

    name = "NUMBER|SEVERITY"

    def convert(self, value: Any, param: Any, ctx: Any) -> float | str:
        if isinstance(value, float | int):
            return value
        if str(value).lower() in SEVERITIES:
            return str(value).lower()
        try:
            return float(value)
        except ValueError:
            self.fail(f"{value!r}: expected a number or one of {', '.join(SEVERITIES)}")


STRENGTH = _Strength()


@click.command("weather")
@click.argument("scan", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("output", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--sensor", required=True, help="Profile name (see `lads profiles`).")
@click.option(
    "--columns",
    type=click.IntRange(min=4),
    default=None,
    help="float32 columns per point (default: 5 if the profile has a ring column, else 4).",
)
@click.option("--rain", type=STRENGTH, help="Rain rate in mm/h, or light, moderate, heavy.")
@click.option(
    "--snow",
    type=STRENGTH,
    help="Snowfall rate (water equivalent) in mm/h, or light, moderate, heavy.",
)
@click.option("--fog", type=STRENGTH, help="Fog visibility (MOR) in m, or light, moderate, heavy.")
@weather_physics_options(default_mode="strongest", default_settings="lads")
@seed_option(help_text="Seed of the weather's random draws.")
@click.option(
    "--labels",
    "labels_in",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Per-point labels to carry along: uint32 (SemanticKITTI) or uint8 (nuScenes "
    "lidarseg), told apart by the file's size.",
)
@click.option(
    "--labels-out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Where to write the carried labels (default: OUTPUT with the suffix .label).",
)
@click.option(
    "--particle-label",
    type=click.IntRange(min=0),
    help="Class of the particle returns (drops, flakes, fog echoes) in the written labels; "
    f"needed with --labels. The datasets' own: {_datasets_particle_labels()}.",
)
def weather_command(
    scan: Path,
    output: Path,
    sensor: str,
    columns: int | None,
    rain: float | str | None,
    snow: float | str | None,
    fog: float | str | None,
    mode: str,
    weather_settings: str,
    detection: str | float | None,
    seed: int,
    labels_in: Path | None,
    labels_out: Path | None,
    particle_label: int | None,
) -> None:
    """Apply one weather to a headerless float32 scan (KITTI .bin, nuScenes .pcd.bin).

    Extra columns (e.g. the nuScenes ring) follow each output point's source beam; so do the
    labels, except on particle returns, which get --particle-label.
    """
    from lads.readers.base import read_records
    from lads.sensors.profile import load_profile

    chosen = {k: v for k, v in (("rain", rain), ("snow", snow), ("fog", fog)) if v is not None}
    if len(chosen) != 1:
        raise click.UsageError("give exactly one of --rain, --snow, --fog")
    if labels_in is not None and particle_label is None:
        raise click.UsageError(_particle_label_hint())
    if labels_in is None and (labels_out is not None or particle_label is not None):
        raise click.UsageError("--labels-out and --particle-label apply to --labels: pass it")
    if scan.suffix.lower() in TEXT_SUFFIXES:
        raise click.UsageError(
            f"{scan}: a text scan; lads weather reads headerless float32 records (KITTI .bin, "
            "nuScenes .pcd.bin). Build RADIATE's .csv scans with `lads build --source radiate`."
        )
    ((name, strength),) = chosen.items()
    stage = _stage(name, strength, mode, weather_settings, detection)
    profile = load_profile(sensor)
    ncol = columns or (5 if profile.has_ring_column else 4)
    # A lone file has no reader's layout: the shared record helpers read it (readers/base.py).
    what = f"a scan of {ncol} float32 columns (pass --columns with the file's column count)"
    points = read_records(scan, np.float32, ncol, what)
    labels = None if labels_in is None else _read_labels(labels_in, len(points), scan)
    if labels is not None and particle_label is not None:
        _check_fits(particle_label, labels.dtype)
    result = stage.simulate(points[:, :3], points[:, 3], profile, np.random.default_rng(seed))
    out = points[result.source_index].copy()
    out[:, :3] = result.xyz
    out[:, 3] = result.intensity
    atomic_write(output, out.tobytes())
    if labels is not None:
        target = labels_out or output.with_suffix(".label")
        atomic_write(target, _carried(labels, result, particle_label).tobytes())
    click.echo(_summary(output, out.shape[0], result, stage))


def _stage(
    name: str, strength: float | str, mode: str, settings: str, detection: str | float | None
) -> WeatherStage:
    """The build's weather stage with these parameters, checked as a pipeline's are."""
    from lads.stage_params import check_stage, resolved
    from lads.stages.weather import WeatherStage

    key = "visibility_m" if name == "fog" else "rate_mm_h"
    params: dict[str, Any] = {"mode": mode, "settings": settings}
    if isinstance(strength, str):
        params["severity"] = strength
    else:
        params[key] = strength
    if detection is not None:
        params["detection"] = detection
    where = f"--{name}"
    params = resolved(name, params, where)
    check_stage(name, params, where)
    return WeatherStage(name=name, **params)


def _particle_label_hint() -> str:
    return (
        "--labels needs --particle-label: rain, snow and fog add returns of drops, flakes and "
        "fog that belong to no class of the scan. The datasets' own: "
        f"{_datasets_particle_labels()}."
    )


def _read_labels(path: Path, n_points: int, scan: Path) -> npt.NDArray[Any]:
    """(N,) labels of one of LABEL_DTYPES, the one whose record count matches the scan."""
    from lads.readers.base import read_labels

    size = path.stat().st_size
    for dtype in LABEL_DTYPES:
        if size == n_points * dtype.itemsize:
            return read_labels(path, dtype, n_points, f"{dtype.name} labels", scan)
    raise ConfigError(
        f"{path}: {size} bytes, but scan {scan} has {n_points} points: expected "
        + " or ".join(f"{n_points * d.itemsize} ({d.name} labels)" for d in LABEL_DTYPES)
        + ". Pass the label file of this scan."
    )


def _check_fits(particle_label: int, dtype: np.dtype) -> None:
    from lads.correspondence import label_fits

    if not label_fits(particle_label, dtype):
        raise ConfigError(
            f"--particle-label {particle_label} does not fit the {dtype.name} labels "
            f"(0..{np.iinfo(dtype).max}); pass a class id of that label set."
        )


def _carried(
    labels: npt.NDArray[Any], result: WeatherResult, particle_label: int | None
) -> npt.NDArray[Any]:
    """Each output point's label: its source beam's, or the particle label on a particle
    return (class and instance: the build's physical-mode rule, `lads.correspondence`)."""
    from lads.physics.result import Outcome

    carried = labels[result.source_index]
    carried[result.outcome == Outcome.PARTICLE] = particle_label
    return carried


def _summary(output: Path, n_out: int, result: WeatherResult, stage: WeatherStage) -> str:
    c = result.counts()
    strength = (
        f"visibility {stage.visibility_m:g} m"
        if stage.name == "fog"
        else f"rate {stage.rate_mm_h:g} mm/h"
    )
    preset = f" ({stage.severity} preset)" if stage.severity else ""
    return (
        f"{output}: {n_out} points (attenuated {c['attenuated']}, particle {c['particle']}, "
        f"lost {c['lost']}); {stage.name} {strength}{preset}, {stage.mode} return, "
        f"{stage.settings} settings, detection {_detection_words(stage)}; "
        f"alpha = {result.extinction_per_m:.3e} 1/m"
    )


def _detection_words(stage: WeatherStage) -> str:
    """The detection rule the stage ran with, as `--detection` names it."""
    if stage.detection is not None:
        return str(stage.detection)
    if stage.settings == "lisa":
        return "LISA's fixed threshold"
    return "sensor (its detection limit)"
