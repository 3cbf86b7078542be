"""`lads diagnose`: the command line of lads/diagnose (run.py does the work)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import click


@click.command("diagnose")
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
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0))
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
    type=click.IntRange(min=0),
    help="Selection reruns on group-bootstrap resamples (stability).",
)
@click.option(
    "--bootstrap", default=None, type=click.IntRange(min=0), help="Bootstrap refits for the CIs."
)
@click.option(
    "--jobs",
    default=None,
    type=click.IntRange(min=1),
    help="Processes for the resamples and bootstrap refits [default: 2]; the report does not "
    "depend on it.",
)
def diagnose_command(
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
    for warning in doc.get("warnings") or []:
        click.echo(f"warning: {warning}", err=True)
    names = ", ".join(_named(e) for e in doc["effects"]) or "none"
    click.echo(f"verdict: {doc['verdict']}; effects: {names}; report: {out / 'report.md'}")


def _named(effect: dict[str, Any]) -> str:
    """An effect as the one-line summary names it: ID, key, its class where it is confined
    to one, and "(possible)" unless it is claimed."""
    cls = f"[{effect['class']}]" if effect.get("class") else ""
    status = "" if effect.get("status") == "claimed" else f" ({effect.get('status')})"
    return f"{effect['id']}{cls} {effect['key']}{status}"
