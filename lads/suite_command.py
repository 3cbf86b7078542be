"""`lads suite`: build the robustness suite of one source (lads.suite)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from lads.cli_options import (
    SOURCE,
    SOURCE_ROOT,
    comma_list,
    jobs_option,
    reader_options,
    seed_option,
)
from lads.exit_codes import EXIT_INCOMPLETE
from lads.physics.severity import SEVERITIES


@click.command("suite")
@SOURCE
@SOURCE_ROOT
@click.option(
    "--out",
    "out_root",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Suite root: one tree per variant below it, and suite.json.",
)
@click.option(
    "--corruptions",
    help="Comma-separated corruptions (default: every one the source can take; "
    "`lads variants` lists them as C-<corruption>-<severity>).",
)
@click.option("--severities", help=f"Comma-separated severities (default: {','.join(SEVERITIES)}).")
@seed_option()
@jobs_option()
@click.option("--sequences", help="Comma-separated sequences to build (as lads build).")
@click.option("--version", "nuscenes_version", help="nuScenes table version.")
@click.option(
    "--limit",
    type=click.IntRange(min=1),
    help="Only the first N items of each tree (trial runs).",
)
@click.option("--figures/--no-figures", default=True, show_default=True)
def suite_command(
    source: str,
    source_root: Path,
    out_root: Path,
    corruptions: str | None,
    severities: str | None,
    seed: int,
    jobs: int,
    sequences: str | None,
    nuscenes_version: str | None,
    limit: int | None,
    figures: bool,
) -> None:
    """Build every corruption at every severity (a SemanticKITTI-C-style suite) from one
    source: one verified tree with its card per C-<corruption>-<severity> variant."""
    from lads.suite import build_suite, suite_variants

    options = reader_options(sequences, nuscenes_version)
    variants = suite_variants(source, comma_list(corruptions), comma_list(severities))
    report = build_suite(
        source,
        source_root,
        out_root,
        variants,
        seed=seed,
        jobs=jobs,
        reader_options=options,
        limit=limit,
        figures=figures,
    )
    for variant, build in report.builds:
        state = "complete" if build.complete else "INCOMPLETE"
        if build.subset:
            state += f" (trial subset of {build.subset[1]})"
        click.echo(f"{variant:30s} {build.items:6d} items  {state}")
    click.echo(f"suite: {len(report.builds)} trees in {out_root} (suite.json)")
    if not report.complete:
        sys.exit(EXIT_INCOMPLETE)
