"""Pipeline configs: `pipelines/*.yaml` in, frozen dataclasses and a config hash out.

A pipeline is data: its variant name, an ordered list of stages with parameters, and the
writer's point-correspondence mode. Unknown keys are rejected so that a typo never falls
back to a default silently.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from lads.correspondence import POINT_MODES
from lads.errors import ConfigError
from lads.point_format import (
    DEFAULT_POINT_FORMAT,
    PointRecord,
    check_point_format,
    native_record,
    no_sensor_stage,
    target_record,
)
from lads.readers import READERS
from lads.resources import pipelines_dir
from lads.stage_params import SEVERITY_STAGES, STAGE_PARAMS, STRENGTHS, check_stage, resolved
from lads.variant_families import (
    CORRUPTION_PIPELINE,
    CORRUPTION_PREFIX,
    SENSOR_PIPELINE,
    corruption_stage,
    corruption_variants,
    describe_variants,
    sensor_variants,
)

SCHEMA_VERSION = 1
# Stages that may follow a sensor transfer: they keep its points (a weather stage would mix
# the transfer's provenance with its own).
_AFTER_SENSOR = ("intensity",)
# `--intensity physics` removes the learned intensity stage (physics intensity is kept).
PHYSICS_INTENSITY = "physics"


@dataclass(frozen=True, slots=True)
class StageConfig:
    """One stage of a pipeline: its name and parameters (plain JSON-able values)."""

    stage: str
    params: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, **self.params}

    def params_hash(self) -> str:
        """sha256 (hex, first 16 chars) of the canonical JSON of this stage's parameters."""
        return _hash(self.to_dict())[:16]


@dataclass(frozen=True, slots=True)
class PipelineConfig:
    """An effective pipeline: what `lads build` runs and records.

    Attributes:
        variant: name of the built variant; part of every item's random-seed identity.
        stages: ordered stages.
        points: "physical" or "aligned" (docs/output_tree.md).
        particle_label: label of particle returns in physical mode; None = reader default.
        description: free text.
        sources: the readers (`--source`) this pipeline applies to; empty = every reader.
        point_format: "source" or "target" (sensor pipelines only): the scans' point record,
            the source's or the target sensor's native one (`lads.point_format`).
    """

    variant: str
    stages: tuple[StageConfig, ...]
    points: str = "physical"
    particle_label: int | None = None
    description: str = ""
    sources: tuple[str, ...] = ()
    point_format: str = DEFAULT_POINT_FORMAT

    def __post_init__(self) -> None:
        if not self.variant or not self.variant.replace("-", "").replace("_", "").isalnum():
            raise ConfigError(
                f"variant {self.variant!r}: expected a short name of letters, digits, '-' or '_'."
            )
        if self.points not in POINT_MODES:
            raise ConfigError(
                f"writer.points is {self.points!r}; expected one of {', '.join(POINT_MODES)}."
            )
        dual = [s.stage for s in self.stages if s.params.get("mode") == "dual"]
        if dual and self.points == "aligned":
            raise ConfigError(
                f"stage {dual[0]} has mode: dual, but writer.points is aligned: an aligned "
                "tree keeps one row per source beam and cannot hold a beam's second return. "
                "Use points: physical (both returns written, strongest first) or another mode."
            )
        self._check_sensor_stage()
        check_point_format(self.point_format, self.sensor_target(), self.variant)
        if self.particle_label is not None and not 0 <= self.particle_label < 2**16:
            raise ConfigError(
                f"writer.particle_label is {self.particle_label}; expected a class id in 0..65535."
            )

    def _check_sensor_stage(self) -> None:
        """A sensor stage comes first, once, followed only by _AFTER_SENSOR stages, and
        writes in resampled mode; resampled mode needs a sensor stage."""
        names = [s.stage for s in self.stages]
        if "sensor" not in names:
            if self.points == "resampled":
                raise ConfigError(
                    "writer.points is resampled, which only a sensor stage writes; use "
                    "physical or aligned, or add a sensor stage."
                )
            return
        later = [n for n in names[1:] if n not in _AFTER_SENSOR]
        if names[0] != "sensor" or later:
            raise ConfigError(
                f"stages {names}: a sensor stage must come first, followed only by "
                f"{', '.join(_AFTER_SENSOR)}; for weather, build it from the transferred tree "
                "with --sensor (docs/transfer.md §3)."
            )
        if self.points != "resampled":
            raise ConfigError(
                f"writer.points is {self.points!r}, but a sensor stage writes new beams: "
                "set writer.points to resampled."
            )

    def sensor_target(self) -> str | None:
        """The target profile of the sensor stage, None without one."""
        targets = [s.params["target"] for s in self.stages if s.stage == "sensor"]
        return str(targets[0]) if targets else None

    def output_sensor(self, source_sensor: str) -> str:
        """The sensor profile of the built tree's scans: a sensor stage's target, else the
        source's own."""
        return self.sensor_target() or source_sensor

    def point_record(self) -> PointRecord | None:
        """The target's native record the scans are written in (point_format "target"),
        None when they keep the source's. Raises PointFormatError: the target has none."""
        target = self.sensor_target()
        return native_record(target) if self.point_format == "target" and target else None

    def to_dict(self) -> dict[str, Any]:
        """Canonical dict as saved in OUT/pipeline.yaml; `sources`, `point_format` when set."""
        writer: dict[str, Any] = {"points": self.points, "particle_label": self.particle_label}
        if self.point_format != DEFAULT_POINT_FORMAT:  # absent: older trees keep their hash
            writer["point_format"] = self.point_format
        out = {
            "schema_version": SCHEMA_VERSION,
            "variant": self.variant,
            "description": self.description,
            "stages": [s.to_dict() for s in self.stages],
            "writer": writer,
        }
        if self.sources:
            out["sources"] = list(self.sources)
        return out

    def check_source(self, source: str, where: str) -> None:
        """Raise ConfigError if this pipeline is not meant for reader `source`, or
        PointFormatError if a `source` tree cannot hold its record (`target_record`)."""
        if self.sources and source not in self.sources:
            raise ConfigError(
                f"{where}: applies to sources {', '.join(self.sources)}, not {source!r} (its "
                "'sources' list)."
            )
        target = self.sensor_target()
        if self.point_format == "target" and target is not None:
            target_record(source, target)

    def config_hash(self) -> str:
        """sha256 hex of the canonical JSON (sorted keys, no spaces) of `to_dict()`."""
        return _hash(self.to_dict())

    def with_overrides(self, **overrides: Any) -> PipelineConfig:
        """A copy with command-line overrides applied; None values are ignored.

        Stage parameters (rate_mm_h, visibility_m, mode, device) go to every stage that
        accepts them; `intensity="physics"` drops the learned intensity stage and any other
        value names its model; `points`, `particle_label`, `point_format` (sensor stage
        only) go to the writer. A stage
        parameter no stage accepts is an error, so `--visibility-m` on a snow pipeline is refused.
        `severity` replaces the weather stages' rate or visibility by its preset's (both are
        recorded); an explicit rate or visibility replaces a preset of the pipeline file, and
        the two together are refused unless they agree.
        """
        given = {k: v for k, v in overrides.items() if v is not None}
        severity = given.pop("severity", None)
        top = {k: given.pop(k) for k in ("points", "particle_label", "point_format") if k in given}
        if "point_format" in top and self.sensor_target() is None:
            raise no_sensor_stage(self.variant, "--point-format")
        stages = list(self.stages)
        intensity = given.pop("intensity", None)
        if intensity is not None:
            learned = [s for s in stages if s.stage == "intensity"]
            if intensity == PHYSICS_INTENSITY:
                stages = [s for s in stages if s.stage != "intensity"]
            elif not learned:
                raise ConfigError(
                    "--intensity MODEL: this pipeline has no intensity stage; add one to the "
                    "pipeline file, or pass --intensity physics."
                )
            else:
                model = absolute_model(intensity, Path.cwd())
                stages = [
                    StageConfig(s.stage, {**s.params, "model": model})
                    if s.stage == "intensity"
                    else s
                    for s in stages
                ]
            if not stages:
                raise ConfigError(
                    "--intensity physics leaves no stage: this pipeline only changes intensity."
                )
        for key, value in given.items():
            hit = [i for i, s in enumerate(stages) if key in STAGE_PARAMS.get(s.stage, {})]
            if not hit:
                names = ", ".join(s.stage for s in stages)
                raise ConfigError(
                    f"--{key.replace('_', '-')} does not apply to this pipeline (stages: {names})."
                )
            for i in hit:
                stage = stages[i]
                params = {**stage.params, key: value}
                if key in STRENGTHS and severity is None:
                    params.pop("severity", None)  # the explicit value replaces the preset
                check_stage(stage.stage, params, f"override {key}")
                stages[i] = StageConfig(stage.stage, params)
        if severity is not None:
            stages = _with_severity_override(stages, severity, given)
        return replace(self, stages=tuple(stages), **top)


def _with_severity_override(
    stages: list[StageConfig], severity: str, given: dict[str, Any]
) -> list[StageConfig]:
    """`--severity`: every weather stage takes the preset, replacing the strength of the
    pipeline file (but not one given on the command line: that must agree)."""
    hit = [i for i, s in enumerate(stages) if s.stage in SEVERITY_STAGES]
    if not hit:
        names = ", ".join(s.stage for s in stages)
        raise ConfigError(f"--severity does not apply to this pipeline (stages: {names}).")
    for i in hit:
        stage = stages[i]
        params = {k: v for k, v in stage.params.items() if k not in STRENGTHS or k in given}
        params = resolved(stage.stage, {**params, "severity": severity}, "override severity")
        check_stage(stage.stage, params, "override severity")
        stages[i] = StageConfig(stage.stage, params)
    return stages


def _hash(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _reject_unknown(mapping: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(mapping) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown}; allowed: {sorted(allowed)}.")


def parse_pipeline(data: Any, where: str) -> PipelineConfig:
    """Validate a loaded pipeline mapping (see pipelines/README.md) into a PipelineConfig."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a YAML mapping at the top level.")
    _reject_unknown(
        data, {"schema_version", "variant", "description", "stages", "writer", "sources"}, where
    )
    if data.get("schema_version") != SCHEMA_VERSION:
        raise ConfigError(
            f"{where}: schema_version is {data.get('schema_version')!r}; this lads reads "
            f"version {SCHEMA_VERSION}."
        )
    raw_stages = data.get("stages")
    if not isinstance(raw_stages, list) or not raw_stages:
        raise ConfigError(f"{where}: 'stages' must be a non-empty list.")
    stages = []
    for i, raw in enumerate(raw_stages):
        if not isinstance(raw, dict) or "stage" not in raw:
            raise ConfigError(f"{where}: stages[{i}] must be a mapping with a 'stage' key.")
        params = {k: v for k, v in raw.items() if k != "stage"}
        params = resolved(str(raw["stage"]), params, f"{where}: stages[{i}]")
        check_stage(str(raw["stage"]), params, f"{where}: stages[{i}]")
        stages.append(StageConfig(str(raw["stage"]), params))
    writer = data.get("writer") or {}
    if not isinstance(writer, dict):
        raise ConfigError(f"{where}: 'writer' must be a mapping.")
    _reject_unknown(writer, {"points", "particle_label", "point_format"}, f"{where}: writer")
    sources = data.get("sources") or []
    if not isinstance(sources, list) or not all(isinstance(s, str) and s for s in sources):
        raise ConfigError(f"{where}: 'sources' must be a list of reader names.")
    if "variant" not in data:
        raise ConfigError(f"{where}: no 'variant' key; name the variant the pipeline builds.")
    try:
        return PipelineConfig(
            variant=str(data["variant"]),
            stages=tuple(stages),
            points=str(writer.get("points", "physical")),
            particle_label=writer.get("particle_label"),
            description=str(data.get("description", "")),
            sources=tuple(sources),
            point_format=str(writer.get("point_format") or DEFAULT_POINT_FORMAT),
        )
    except ConfigError as exc:  # the checks of the whole pipeline: name the file too
        raise type(exc)(f"{where}: {exc}") from None


def load_pipeline(path: Path) -> PipelineConfig:
    """Read and validate one pipeline YAML. Raises ConfigError naming the file."""
    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the pipeline file ({exc}).") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc}).") from exc
    pipeline = parse_pipeline(data, str(path))
    base = Path(path).resolve().parent
    stages = tuple(
        StageConfig(s.stage, {**s.params, "model": absolute_model(s.params["model"], base)})
        if s.stage == "intensity" and isinstance(s.params.get("model"), str)
        else s
        for s in pipeline.stages
    )
    return replace(pipeline, stages=stages)


def absolute_model(model: str, base: Path) -> str:
    """An intensity model as the pipeline records it: a shipped name as it is, a weight file
    (a `.pt` name or a path) absolute, taken from `base` when relative (the working folder
    for --intensity, a pipeline file's folder for its `model`), so the recorded pipeline
    means the same file from any folder."""
    if not (model.endswith(".pt") or "/" in model or "\\" in model):
        return model
    path = Path(model).expanduser()
    return str(path if path.is_absolute() else (base / path).resolve())


def _pipeline_files(directory: Path) -> dict[str, Path]:
    return {p.stem: p for p in sorted(directory.glob("*.yaml"))}


def variants_for(source: str, directory: Path | None = None) -> list[str]:
    """The variants `lads build --source source --variant V` accepts, sorted.

    A variant is `<source>-<V>.yaml` or, when no such file exists, `<V>.yaml` whose
    `sources` (if any) name `source`; another source's `<other>-<V>.yaml` is not a variant
    of this one.
    """
    files = _pipeline_files(directory or pipelines_dir())
    names = set()
    for stem, path in files.items():
        owner = _source_prefix(stem)
        if owner is not None:
            if owner == source:
                names.add(stem[len(owner) + 1 :])
        elif stem == CORRUPTION_PIPELINE:
            names.update(corruption_variants(source))
        elif source in (load_pipeline(path).sources or (source,)):
            names.update(sensor_variants(source) if stem == SENSOR_PIPELINE else [stem])
    return sorted(names)


def pipeline_for(source: str, variant: str, directory: Path | None = None) -> PipelineConfig:
    """The shipped pipeline of (source, variant), loaded (`find_pipeline`); a
    `sensor-<profile>` variant is sensor.yaml with that target.

    Raises:
        ConfigError: no such variant for this source (as `find_pipeline`).
    """
    path = find_pipeline(source, variant, directory)
    pipeline = load_pipeline(path)
    if path.stem == CORRUPTION_PIPELINE and variant != CORRUPTION_PIPELINE:
        stage, params, description = corruption_stage(variant)
        only = (StageConfig(stage, params),)
        return replace(pipeline, variant=variant, stages=only, description=description)
    if path.stem != SENSOR_PIPELINE or variant == SENSOR_PIPELINE:
        return pipeline
    target = variant[len(SENSOR_PIPELINE) + 1 :]
    stages = tuple(
        StageConfig(s.stage, {**s.params, "target": target}) if s.stage == "sensor" else s
        for s in pipeline.stages
    )
    return replace(pipeline, variant=variant, stages=stages)


def _source_prefix(stem: str) -> str | None:
    """The reader a `<source>-<variant>` file name belongs to (the longest matching name)."""
    owners = [r for r in READERS if stem.startswith(f"{r}-") and len(stem) > len(r) + 1]
    return max(owners, key=len) if owners else None


def find_pipeline(source: str, variant: str, directory: Path | None = None) -> Path:
    """The shipped pipeline of (source, variant): `<source>-<variant>.yaml` if present, else
    `<variant>.yaml` when it applies to `source`.

    Raises:
        ConfigError: no such variant for this source; the message lists the valid ones and
            the sources that do have the variant.
    """
    directory = directory or pipelines_dir()
    files = _pipeline_files(directory)
    own = files.get(f"{source}-{variant}")
    if own is not None:
        return own
    valid = variants_for(source, directory)
    if variant in valid:
        if variant in files:
            return files[variant]
        generic = CORRUPTION_PIPELINE if variant.startswith(CORRUPTION_PREFIX) else SENSOR_PIPELINE
        return files[generic]
    others = [s for s in sorted(READERS) if s != source and variant in variants_for(s, directory)]
    elsewhere = f" '{variant}' exists for: {', '.join(others)}." if others else ""
    raise ConfigError(
        f"no pipeline for source {source!r} and variant {variant!r} in {directory}; "
        f"variants of {source!r}: {describe_variants(valid) or 'none'}.{elsewhere} "
        "Pass --pipeline FILE to use your own."
    )
