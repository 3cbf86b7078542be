"""`lads verify OUT`: check a built tree against its manifest and its source (lads.verify)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from lads.cli_options import seed_option
from lads.exit_codes import EXIT_INCOMPLETE
from lads.files import atomic_write


@click.command("verify")
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
@seed_option("Seed for choosing items to regenerate.")
@click.option(
    "--json",
    "json_out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also write the report as JSON.",
)
def verify_command(
    out_root: Path,
    source_root: Path | None,
    regenerate: int,
    inventory: str | None,
    seed: int,
    json_out: Path | None,
) -> None:
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
