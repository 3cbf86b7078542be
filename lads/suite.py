"""The robustness suite: every `C-<corruption>-<severity>` variant of one source and its
`sensor-<profile>` variants (cross-sensor), each its own verified tree with its card, plus
`suite.json` listing them (docs/augment.md §4).

`lads suite --source semantickitti --in ROOT --out SUITE` builds a SemanticKITTI-C-style set:
SUITE/C-fog-light, SUITE/C-fog-moderate, ... Each tree is an ordinary `lads build`, so an
interrupted suite resumes where it stopped and `lads verify` checks every tree.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lads.config import pipeline_for, variants_for
from lads.corruptions import corruption_spec
from lads.errors import ConfigError
from lads.files import atomic_write
from lads.physics.severity import SEVERITIES
from lads.runner import BuildReport, run_build
from lads.variant_families import SENSOR_PIPELINE, corruption_variants, split_corruption_variant

SUITE_FILE = "suite.json"
SUITE_README = "README.md"
# The corruption whose trees are the sensor-<profile> variants.
CROSS_SENSOR = "cross_sensor"
# The motion-distortion tree at the motion each frame's poses recorded (sources with poses),
# and the "severity" the suite lists it under.
RECORDED_MOTION, RECORDED = "motion-recorded", "recorded"


@dataclass(frozen=True, slots=True)
class SuiteReport:
    """What `build_suite` did: the report of each variant's build, in suite order."""

    out_root: Path
    builds: tuple[tuple[str, BuildReport], ...]

    @property
    def complete(self) -> bool:
        return all(report.complete for _, report in self.builds)


def suite_variants(
    source: str, corruptions: list[str] | None = None, severities: list[str] | None = None
) -> list[str]:
    """The suite's variants for `source`: `C-<corruption>-<severity>` for every corruption
    with severities, `motion-recorded` for a source with poses (unless `severities` narrows
    the set), and `sensor-<profile>` for cross-sensor (every target profile the source can
    be transferred to). `corruptions` (names or peers' names) and `severities` narrow the
    set; severities do not apply to cross-sensor.

    Raises:
        ConfigError: an unknown corruption or severity, or one this source cannot take.
    """
    names = None if corruptions is None else {corruption_spec(c).name for c in corruptions}
    unknown = sorted(set(severities or ()) - set(SEVERITIES))
    if unknown:
        raise ConfigError(f"severities {unknown}; expected some of {', '.join(SEVERITIES)}.")
    chosen = []
    for variant in corruption_variants(source):
        name, severity = _corruption_of(variant)
        if (names is None or name in names) and (severities is None or severity in severities):
            chosen.append(variant)
    offered = variants_for(source)
    motion = names is None or "motion_distortion" in names
    if motion and severities is None and RECORDED_MOTION in offered:
        chosen.append(RECORDED_MOTION)
    if names is None or CROSS_SENSOR in names:
        chosen += [v for v in offered if v.startswith(f"{SENSOR_PIPELINE}-")]
    missing = sorted((names or set()) - {_corruption_of(v)[0] for v in chosen})
    if missing:
        raise ConfigError(
            f"source {source!r} cannot take {missing}: wet ground and incomplete echo need "
            "point labels, cross-sensor a reader with poses (`lads variants`)."
        )
    return chosen


def _corruption_of(variant: str) -> tuple[str, str | None]:
    """(corruption, severity) of a suite variant; cross-sensor has no severity, and the
    recorded motion is listed as severity "recorded"."""
    if variant == RECORDED_MOTION:
        return "motion_distortion", RECORDED
    if variant.startswith(f"{SENSOR_PIPELINE}-"):
        return CROSS_SENSOR, None
    return split_corruption_variant(variant)


def build_suite(
    source: str,
    source_root: Path,
    out_root: Path,
    variants: list[str],
    **build_options: Any,
) -> SuiteReport:
    """Build every variant into out_root/<variant> and write out_root/suite.json.

    Args:
        source: reader name. source_root: the source tree.
        variants: from `suite_variants`.
        **build_options: passed to every `lads.runner.run_build` (seed, jobs, reader_options,
            backend, figures, limit, ...).
    """
    builds = []
    for variant in variants:
        pipeline = pipeline_for(source, variant)
        report = run_build(source, source_root, out_root / variant, pipeline, **build_options)
        builds.append((variant, report))
    suite = SuiteReport(out_root, tuple(builds))
    summary = _summary(source, suite)
    atomic_write(out_root / SUITE_FILE, (json.dumps(summary, indent=2) + "\n").encode())
    atomic_write(out_root / SUITE_README, _readme(summary).encode())
    return suite


def _readme(summary: dict[str, Any]) -> str:
    """The suite's front page: one row per tree, linking its dataset card."""
    lines = [
        f"# Robustness suite of {summary['source']}",
        "",
        "Built by `lads suite` (docs/augment.md of lads): one tree per corruption and severity,",
        "each with its own dataset card, manifest and provenance; `suite.json` holds this table.",
        "",
        "| tree | corruption | severity | physical value | items | complete |",
        "|---|---|---|---|---|---|",
    ]
    if summary.get("trial_subset"):
        lines[5:5] = ["A trial subset (`--limit`): the trees hold the first items only.", ""]
    for row in summary["variants"]:
        spec = corruption_spec(row["corruption"])
        if row["severity"] is None:
            value = f"target {row['target']}"
        elif row["severity"] == RECORDED:
            value = f"{spec.parameter} {row[spec.parameter]}"
        else:
            value = f"{spec.parameter} = {row[spec.parameter]:g}"
        lines.append(
            f"| [{row['tree']}]({row['tree']}/README.md) | {row['corruption']} | "
            f"{row['severity'] or '-'} | {value} | {row['items']} | {row['complete']} |"
        )
    return "\n".join(lines) + "\n"


def _summary(source: str, suite: SuiteReport) -> dict[str, Any]:
    rows = []
    for variant, report in suite.builds:
        name, severity = _corruption_of(variant)
        spec = corruption_spec(name)
        row: dict[str, Any] = {
            "variant": variant,
            "corruption": name,
            "peer_names": list(spec.peer_names),
            "severity": severity,
        }
        if severity is None:
            row["target"] = variant[len(SENSOR_PIPELINE) + 1 :]
        elif severity == RECORDED:
            row[spec.parameter] = "per frame, from the poses (manifest conditions)"
        else:
            row[spec.parameter] = spec.preset(severity)
        rows.append(
            {
                **row,
                "tree": variant,
                "items": report.items,
                "complete": report.complete,
                "source_items": report.subset[1] if report.subset else report.items,
            }
        )
    trial = any(report.subset for _, report in suite.builds)
    return {"source": source, "complete": suite.complete, "trial_subset": trial, "variants": rows}
