"""Variant families: variants made from one shipped pipeline by filling in a parameter.

- `sensor-<profile>`: pipelines/sensor.yaml with that target sensor.
- `C-<corruption>-<severity>`: pipelines/corruption.yaml with that corruption's stage at that
  severity preset, the robustness suite (docs/augment.md §3).

`lads.config` lists and loads them; this module only names them and resolves their stage.
"""

from __future__ import annotations

from typing import Any

from lads.corruptions import CORRUPTIONS, corruption_spec
from lads.errors import ConfigError
from lads.physics.severity import SEVERITIES
from lads.stage_params import check_stage, resolved

# pipelines/sensor.yaml holds the settings of every `sensor-<profile>` variant: the variant
# `sensor-P` is that pipeline with the target P (`lads.config.pipeline_for`).
SENSOR_PIPELINE = "sensor"
# pipelines/corruption.yaml is the pipeline every `C-<corruption>-<severity>` variant is made from.
CORRUPTION_PIPELINE = "corruption"
CORRUPTION_PREFIX = "C-"


def sensor_variants(source: str) -> list[str]:
    """`sensor-<profile>` for every shipped profile but the source's own sensor."""
    from lads.readers import reader_class
    from lads.sensors.profile import available_profiles

    own = reader_class(source).sensor
    return [f"{SENSOR_PIPELINE}-{p}" for p in available_profiles() if p != own]


def corruption_variants(source: str) -> list[str]:
    """`C-<corruption>-<severity>` for every corruption of `lads.augment.CORRUPTIONS` this
    source can take (wet ground needs a labelled source), at every severity."""
    from lads.readers import label_set_for

    labelled = label_set_for(source) is not None
    return [
        f"{CORRUPTION_PREFIX}{name}-{severity}"
        for name, spec in CORRUPTIONS.items()
        if spec.has_presets and (labelled or not spec.needs_labels)
        for severity in SEVERITIES
    ]


def split_corruption_variant(variant: str) -> tuple[str, str]:
    """(corruption, severity) of a `C-<corruption>-<severity>` name; the corruption name may
    hold underscores but no dashes, so the severity is what follows the last dash."""
    name, _, severity = variant[len(CORRUPTION_PREFIX) :].rpartition("-")
    return name, severity


def corruption_stage(variant: str) -> tuple[str, dict[str, Any], str]:
    """(stage name, its parameters, a description) of a `C-<corruption>-<severity>` variant.

    Raises:
        ConfigError: not such a variant, or an unknown corruption or severity.
    """
    name, severity = split_corruption_variant(variant)
    if not variant.startswith(CORRUPTION_PREFIX) or severity not in SEVERITIES:
        raise ConfigError(
            f"variant {variant!r}: expected {CORRUPTION_PREFIX}<corruption>-<severity> with a "
            f"severity of {', '.join(SEVERITIES)}."
        )
    spec = corruption_spec(name)
    where = f"variant {variant}"
    params = resolved(spec.stage, {"severity": severity}, where)
    check_stage(spec.stage, params, where)
    value = f"{spec.parameter} = {spec.preset(severity):g}"
    return spec.stage, params, f"{spec.summary} ({severity}: {value})"


def describe_variants(variants: list[str]) -> str:
    """The variants as a short list for messages: the suite's `C-` variants folded into one
    entry naming their corruptions and severities."""
    suite = [v for v in variants if v.startswith(CORRUPTION_PREFIX)]
    others = [v for v in variants if not v.startswith(CORRUPTION_PREFIX)]
    if suite:
        names = sorted({split_corruption_variant(v)[0] for v in suite})
        others.append(
            f"{CORRUPTION_PREFIX}<corruption>-<{'|'.join(SEVERITIES)}> for {'|'.join(names)}"
        )
    return ", ".join(others)


def fold_severity(variant: str) -> str:
    """A suite variant with its severity spelled as the choice of all of them
    (`C-fog-<light|moderate|heavy>`); any other variant unchanged."""
    if not variant.startswith(CORRUPTION_PREFIX):
        return variant
    return f"{CORRUPTION_PREFIX}{split_corruption_variant(variant)[0]}-<{'|'.join(SEVERITIES)}>"
