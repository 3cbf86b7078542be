"""The schema of `lads/physics/materials.yaml`: its materials and label sets, validated into
lookup arrays (`parse_table`). `lads.physics.materials` loads the shipped file and answers
questions about labels; docs/physics.md §10.2 is the reference table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError

LABEL_SETS: tuple[str, ...] = ("semantickitti", "nuscenes", "voxelscape", "wads")
MAX_REFLECTANCE = 1.2
MAX_CLASS_ID = 0xFFFF
OUT_OF_RANGE = MAX_CLASS_ID + 1  # lookup slot for ids above 0xFFFF (unmasked label sets)
FINISHES: tuple[str, ...] = ("clearcoat", "retroreflective")
CLASS_FLAGS = ("ground", "flat", "moving", "ego")  # optional true/false keys of a class


@dataclass(frozen=True, slots=True)
class Material:
    """One material: diffuse reflectance at 905 nm (unitless) and where the value comes from.

    texture_depth_mm: mean texture depth of a ground surface of this material, mm (how much
    water it holds before a film covers it, docs/physics.md §8); None for non-ground materials.
    finish: how the surface departs from a diffuse one (one of FINISHES), or None.
    """

    name: str
    reflectance: float
    source: str
    texture_depth_mm: float | None = None
    finish: str | None = None


@dataclass(frozen=True, slots=True)
class LabelSet:
    name: str
    instance_bits: bool
    classes: dict[int, tuple[str, str]]  # class id -> (class name, material name)
    lookup: npt.NDArray[np.float32]  # (MAX_CLASS_ID + 2,) reflectance per id
    known: npt.NDArray[np.bool_]  # (MAX_CLASS_ID + 2,) id has an entry
    material: npt.NDArray[np.int16]  # (MAX_CLASS_ID + 2,) index into material_names()
    ground: npt.NDArray[np.bool_]  # (MAX_CLASS_ID + 2,) class is a ground surface
    flat: frozenset[int]  # classes marked `flat` (level ground that is not road-like)
    moving: frozenset[int]  # classes marked `moving`
    ego: frozenset[int]  # classes marked `ego`


@dataclass(frozen=True, slots=True)
class Table:
    materials: dict[str, Material]
    default: Material
    label_sets: dict[str, LabelSet]


def parse_table(raw: Any, where: str) -> Table:
    """Validate a materials mapping (as loaded from YAML); raise ConfigError naming `where`."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping at top level.")
    _require_keys(raw, {"schema_version", "default_material", "materials", "label_sets"}, where)
    if raw["schema_version"] != 1:
        raise ConfigError(f"{where}: schema_version {raw['schema_version']!r}; expected 1.")
    materials = {name: _material(name, spec, where) for name, spec in raw["materials"].items()}
    default_name = raw["default_material"]
    if default_name not in materials:
        raise ConfigError(f"{where}: default_material '{default_name}' is not a material.")
    sets_raw = raw["label_sets"]
    if not isinstance(sets_raw, dict) or set(sets_raw) != set(LABEL_SETS):
        raise ConfigError(
            f"{where}: label_sets must be exactly {list(LABEL_SETS)}, got "
            f"{sorted(sets_raw) if isinstance(sets_raw, dict) else sets_raw!r}."
        )
    label_sets = {
        name: _label_set(name, sets_raw, materials, materials[default_name], where)
        for name in LABEL_SETS
    }
    return Table(materials, materials[default_name], label_sets)


def _material(name: str, spec: Any, where: str) -> Material:
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: materials.{name} must be a mapping.")
    _require_keys(
        spec,
        {"reflectance", "source"},
        f"{where}: materials.{name}",
        optional=frozenset({"texture_depth_mm", "finish"}),
    )
    finish = spec.get("finish")
    if finish is not None and finish not in FINISHES:
        raise ConfigError(
            f"{where}: materials.{name}.finish = {finish!r}; expected one of {list(FINISHES)}."
        )
    depth = spec.get("texture_depth_mm")
    if depth is not None and (
        isinstance(depth, bool) or not isinstance(depth, int | float) or not depth > 0
    ):
        raise ConfigError(f"{where}: materials.{name}.texture_depth_mm must be a number > 0.")
    rho = spec["reflectance"]
    if isinstance(rho, bool) or not isinstance(rho, int | float):
        raise ConfigError(f"{where}: materials.{name}.reflectance must be a number.")
    if not 0.0 <= rho <= MAX_REFLECTANCE:
        raise ConfigError(
            f"{where}: materials.{name}.reflectance = {rho}; expected 0 <= rho <= "
            f"{MAX_REFLECTANCE}."
        )
    if not isinstance(spec["source"], str) or not spec["source"].strip():
        raise ConfigError(f"{where}: materials.{name}.source must cite where {rho} comes from.")
    return Material(
        str(name),
        float(rho),
        spec["source"].strip(),
        None if depth is None else float(depth),
        finish,
    )


def _label_set(
    name: str,
    sets_raw: dict[str, Any],
    materials: dict[str, Material],
    default: Material,
    where: str,
) -> LabelSet:
    spec = sets_raw[name]
    ctx = f"{where}: label_sets.{name}"
    if not isinstance(spec, dict):
        raise ConfigError(f"{ctx} must be a mapping.")
    required = {"description", "instance_bits", "classes"}
    _require_keys(spec, required, ctx, optional=frozenset({"extends"}))
    classes, flags = _merged_classes(spec, sets_raw, ctx, where)
    lookup, known, material_of = _class_tables(classes, materials, default, ctx)
    ground = np.zeros(OUT_OF_RANGE + 1, dtype=bool)
    ground[sorted(flags["ground"])] = True
    for table in (lookup, known, material_of, ground):
        table.flags.writeable = False
    return LabelSet(
        name,
        bool(spec["instance_bits"]),
        classes,
        lookup,
        known,
        material_of,
        ground,
        frozenset(flags["flat"]),
        frozenset(flags["moving"]),
        frozenset(flags["ego"]),
    )


def _merged_classes(
    spec: dict[str, Any], sets_raw: dict[str, Any], ctx: str, where: str
) -> tuple[dict[int, tuple[str, str]], dict[str, set[int]]]:
    """`_classes` of a label set over those of the set it `extends` (if any): a class of its
    own replaces the inherited entry and flags of that id."""
    classes: dict[int, tuple[str, str]] = {}
    flags: dict[str, set[int]] = {f: set() for f in CLASS_FLAGS}
    if "extends" in spec:
        base = sets_raw.get(spec["extends"])
        if not isinstance(base, dict) or "extends" in base:
            raise ConfigError(f"{ctx}.extends must name a label set that extends nothing.")
        inherited, flags = _classes(base.get("classes"), f"{where}: label_sets.{spec['extends']}")
        classes.update(inherited)
    own, own_flags = _classes(spec["classes"], ctx)
    classes.update(own)
    return classes, {f: (flags[f] - set(own)) | own_flags[f] for f in CLASS_FLAGS}


def _class_tables(
    classes: dict[int, tuple[str, str]],
    materials: dict[str, Material],
    default: Material,
    ctx: str,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_], npt.NDArray[np.int16]]:
    """(OUT_OF_RANGE + 1,) tables by class id: reflectance (float32; `default`'s where a
    class has no entry), known (bool) and material (int16 index into `materials`)."""
    lookup = np.full(OUT_OF_RANGE + 1, default.reflectance, dtype=np.float32)
    known = np.zeros(OUT_OF_RANGE + 1, dtype=bool)
    order = {m: i for i, m in enumerate(materials)}
    material_of = np.full(OUT_OF_RANGE + 1, order[default.name], dtype=np.int16)
    for class_id, (class_name, material) in classes.items():
        if material not in materials:
            raise ConfigError(
                f"{ctx}: class {class_id} ({class_name}) maps to unknown material "
                f"'{material}'; defined materials: {', '.join(sorted(materials))}."
            )
        lookup[class_id] = materials[material].reflectance
        known[class_id] = True
        material_of[class_id] = order[material]
    return lookup, known, material_of


def _classes(raw: Any, ctx: str) -> tuple[dict[int, tuple[str, str]], dict[str, set[int]]]:
    """Class id -> (name, material), and per flag of CLASS_FLAGS the ids marked true
    (`ground`: road-like surfaces, `flat`: other level ground, `moving`, `ego`)."""
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{ctx}.classes must be a non-empty mapping of class id -> entry.")
    out: dict[int, tuple[str, str]] = {}
    flags: dict[str, set[int]] = {f: set() for f in CLASS_FLAGS}
    for class_id, entry in raw.items():
        if isinstance(class_id, bool) or not isinstance(class_id, int):
            raise ConfigError(f"{ctx}.classes: key {class_id!r} is not an integer class id.")
        if not 0 <= class_id <= MAX_CLASS_ID:
            raise ConfigError(f"{ctx}.classes: id {class_id} outside [0, {MAX_CLASS_ID}].")
        if not isinstance(entry, dict):
            raise ConfigError(f"{ctx}.classes.{class_id} must be a mapping.")
        _require_keys(
            entry,
            {"name", "material"},
            f"{ctx}.classes.{class_id}",
            optional=frozenset(CLASS_FLAGS),
        )
        for flag in CLASS_FLAGS:
            if not isinstance(entry.get(flag, False), bool):
                raise ConfigError(f"{ctx}.classes.{class_id}.{flag} must be true or false.")
            if entry.get(flag, False):
                flags[flag].add(class_id)
        if entry.get("ground", False) and entry.get("flat", False):
            raise ConfigError(
                f"{ctx}.classes.{class_id}: `ground` classes are level already; drop `flat`."
            )
        out[class_id] = (str(entry["name"]), str(entry["material"]))
    return out, flags


def _require_keys(
    spec: dict[str, Any], required: set[str], ctx: str, optional: frozenset[str] = frozenset()
) -> None:
    unknown, missing = set(spec) - required - set(optional), required - set(spec)
    if unknown or missing:
        raise ConfigError(
            f"{ctx}: unknown keys {sorted(unknown)}, missing keys {sorted(missing)}; "
            f"expected {sorted(required | set(optional))}."
        )
