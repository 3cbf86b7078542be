"""Material reflectance at 905 nm per semantic class, from `lads/physics/materials.yaml`.

The YAML is the single source of truth (docs/physics.md §10.2): materials with a reflectance and
a citation each, and one class -> material map per label set. It is read from the package
data once, validated, and turned into one lookup array per label set, so mapping a frame's
labels is a single fancy-indexing operation.
"""

from __future__ import annotations

import functools
import importlib.resources
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from lads.errors import ConfigError, InputDataError

MATERIALS_FILE = "materials.yaml"
LABEL_SETS: tuple[str, ...] = ("semantickitti", "nuscenes", "voxelscape", "wads")
MAX_REFLECTANCE = 1.2
MAX_CLASS_ID = 0xFFFF
_OUT_OF_RANGE = MAX_CLASS_ID + 1  # lookup slot for ids above 0xFFFF (unmasked label sets)
FINISHES: tuple[str, ...] = ("clearcoat", "retroreflective")


class UnknownLabelWarning(UserWarning):
    """Labels without a class -> material entry were given the default reflectance."""


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
class ClassRoles:
    """Class ids of one label set by what their surface does to a beam (materials.yaml).

    Attributes:
        clearcoat: classes whose material has a glossy lacquer (finish `clearcoat`).
        retroreflective: classes whose material returns the beam whatever the incidence.
        road_like: classes marked `ground` (a water film can lie on them).
        level_ground: road_like and the classes marked `flat` (what a ground plane is
            fitted to).
        moving: classes marked `moving` (things in motion when scanned).
        ego: classes marked `ego` (the recording vehicle's own body).
    """

    clearcoat: frozenset[int]
    retroreflective: frozenset[int]
    road_like: frozenset[int]
    level_ground: frozenset[int]
    moving: frozenset[int]
    ego: frozenset[int]


@dataclass(frozen=True, slots=True)
class _LabelSet:
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
class _Table:
    materials: dict[str, Material]
    default: Material
    label_sets: dict[str, _LabelSet]


_warned: dict[str, set[int]] = {}


def reflectance_for_labels(labels: npt.ArrayLike, label_set: str) -> npt.NDArray[np.float32]:
    """Reflectance at 905 nm of each point's material, looked up from its class label.

    Args:
        labels: (N,) any integer dtype, the dataset's stored labels. For label sets with
            instance bits (semantickitti, voxelscape, wads) the class is `label & 0xFFFF`.
        label_set: one of `LABEL_SETS`.

    Returns:
        (N,) float32 reflectance, unitless (retro-reflective sheeting is 1.0). Ids without an
        entry get the default material's 0.20, with one `UnknownLabelWarning` per label set
        the first time each such id is seen in this process.

    Raises:
        ConfigError: unknown label set, or the shipped YAML is invalid.
        InputDataError: labels are not a 1-D integer array, or contain negative values.
    """
    lset, ids = _classes_of(labels, label_set)
    return lset.lookup[ids]


def material_index_for_labels(labels: npt.ArrayLike, label_set: str) -> npt.NDArray[np.int64]:
    """Each point's material as an index into `material_names()`, from its class label.

    The same lookup as `reflectance_for_labels` (ids without an entry get the default
    material, with the same one-time warning), returning *which* material instead of its
    reflectance: two materials of equal reflectance (white paint and clothing, 0.60) stay
    apart, which a learned intensity model needs because a sensor answers them differently.

    Raises:
        ConfigError, InputDataError: as `reflectance_for_labels`.
    """
    lset, ids = _classes_of(labels, label_set)
    return lset.material[ids].astype(np.int64)


def _classes_of(labels: npt.ArrayLike, label_set: str) -> tuple[_LabelSet, npt.NDArray[np.intp]]:
    """The label set and each point's class id (warning once about ids without a material)."""
    lset = _label_set_of(label_set)
    ids = _class_ids(labels, lset.instance_bits)
    unknown = ~lset.known[ids]
    if unknown.any():
        _warn_unknown(lset, labels, unknown)
    return lset, ids


def wet_surface_for_labels(
    labels: npt.ArrayLike, label_set: str
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Which points are ground that holds a water film, and its texture depth.

    Args:
        labels: (N,) stored labels (instance bits allowed where the label set has them).
        label_set: one of LABEL_SETS.

    Returns:
        wettable (N,) bool: the class is marked `ground` and its material has a texture depth;
        texture_depth_mm (N,) float64 (0 where not wettable).
    """
    table = _table()
    lset, ids = _classes_of(labels, label_set)
    depth_of = np.array(
        [m.texture_depth_mm or 0.0 for m in table.materials.values()], dtype=np.float64
    )
    depth = depth_of[lset.material[ids]]
    wettable = lset.ground[ids] & (depth > 0)
    return wettable, np.where(wettable, depth, 0.0)


def material_names() -> tuple[str, ...]:
    """Every material of the shipped YAML, in file order (the order of material indices)."""
    return tuple(_table().materials)


def default_material() -> str:
    """Name of the material given to unlabelled points and unmapped classes."""
    return _table().default.name


def material_table() -> dict[str, Material]:
    """All materials of the shipped YAML by name (a copy; safe to modify)."""
    return dict(_table().materials)


def class_materials(label_set: str) -> dict[int, tuple[str, str]]:
    """Class id -> (class name, material name) for one label set, `extends` resolved."""
    return dict(_label_set_of(label_set).classes)


def class_roles(label_set: str) -> ClassRoles:
    """The classes of `label_set` by role (materials.yaml `finish`, `ground`, `flat`,
    `moving`, `ego`).

    Raises:
        ConfigError: unknown label set.
    """
    table = _table()
    lset = _label_set_of(label_set)

    def finished(finish: str) -> frozenset[int]:
        return frozenset(
            c for c, (_, m) in lset.classes.items() if table.materials[m].finish == finish
        )

    road_like = frozenset(int(c) for c in np.flatnonzero(lset.ground))
    return ClassRoles(finished("clearcoat"), finished("retroreflective"), road_like,
                      road_like | lset.flat, lset.moving, lset.ego)  # fmt: skip


def has_instance_bits(label_set: str) -> bool:
    """Whether `label_set`'s stored labels carry an instance id above their low 16 bits
    (materials.yaml `instance_bits`; the class is then label & MAX_CLASS_ID).

    Raises:
        ConfigError: unknown label set.
    """
    return _label_set_of(label_set).instance_bits


def _label_set_of(label_set: str) -> _LabelSet:
    table = _table()
    if label_set not in table.label_sets:
        raise ConfigError(
            f"unknown label set '{label_set}'; known label sets: {', '.join(LABEL_SETS)}."
        )
    return table.label_sets[label_set]


def _class_ids(labels: npt.ArrayLike, instance_bits: bool) -> npt.NDArray[np.intp]:
    arr = np.asarray(labels)
    if arr.ndim != 1 or not (np.issubdtype(arr.dtype, np.integer) or arr.size == 0):
        raise InputDataError(
            f"labels: expected a 1-D integer array (N,), got shape {arr.shape} and dtype "
            f"{arr.dtype}; read .label files as uint32 and lidarseg files as uint8."
        )
    arr = arr.astype(np.int64, copy=False)
    negative = int(np.count_nonzero(arr < 0))
    if negative:
        raise InputDataError(
            f"labels: {negative} negative values (min {int(arr.min())}); class labels are "
            "non-negative. Int32-read .label files with instance ids >= 32768 must be read "
            "as uint32."
        )
    ids = arr & MAX_CLASS_ID if instance_bits else np.minimum(arr, _OUT_OF_RANGE)
    return ids.astype(np.intp, copy=False)


def _warn_unknown(lset: _LabelSet, labels: npt.ArrayLike, unknown: npt.NDArray[np.bool_]) -> None:
    arr = np.asarray(labels).astype(np.int64, copy=False)
    ids = np.unique(arr[unknown] & MAX_CLASS_ID if lset.instance_bits else arr[unknown])
    seen = _warned.setdefault(lset.name, set())
    new = sorted(set(ids.tolist()) - seen)
    if new:
        seen.update(new)
        default = _table().default
        warnings.warn(
            f"label set '{lset.name}': class ids {new} have no material in {MATERIALS_FILE}; "
            f"those points get the '{default.name}' reflectance {default.reflectance:g}. "
            "Add the classes to lads/physics/materials.yaml if they are real.",
            UnknownLabelWarning,
            stacklevel=3,
        )


@functools.lru_cache(maxsize=1)
def _table() -> _Table:
    resource = importlib.resources.files("lads.physics").joinpath(MATERIALS_FILE)
    try:
        raw = yaml.safe_load(resource.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{MATERIALS_FILE}: cannot read YAML ({exc}).") from exc
    return parse_table(raw, MATERIALS_FILE)


def parse_table(raw: Any, where: str) -> _Table:
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
    return _Table(materials, materials[default_name], label_sets)


def _material(name: str, spec: Any, where: str) -> Material:
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: materials.{name} must be a mapping.")
    _require_keys(
        spec, {"reflectance", "source"}, f"{where}: materials.{name}",
        optional=frozenset({"texture_depth_mm", "finish"}),
    )  # fmt: skip
    finish = spec.get("finish")
    if finish is not None and finish not in FINISHES:
        raise ConfigError(
            f"{where}: materials.{name}.finish = {finish!r}; expected one of {list(FINISHES)}."
        )
    depth = spec.get("texture_depth_mm")
    if depth is not None and (isinstance(depth, bool) or not isinstance(depth, int | float)
                              or not depth > 0):  # fmt: skip
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
        str(name), float(rho), spec["source"].strip(), None if depth is None else float(depth),
        finish,
    )  # fmt: skip


def _label_set(
    name: str,
    sets_raw: dict[str, Any],
    materials: dict[str, Material],
    default: Material,
    where: str,
) -> _LabelSet:
    spec = sets_raw[name]
    ctx = f"{where}: label_sets.{name}"
    if not isinstance(spec, dict):
        raise ConfigError(f"{ctx} must be a mapping.")
    required = {"description", "instance_bits", "classes"}
    _require_keys(spec, required, ctx, optional=frozenset({"extends"}))
    classes: dict[int, tuple[str, str]] = {}
    grounds: set[int] = set()
    flats: set[int] = set()
    movers: set[int] = set()
    egos: set[int] = set()
    if "extends" in spec:
        base = sets_raw.get(spec["extends"])
        if not isinstance(base, dict) or "extends" in base:
            raise ConfigError(f"{ctx}.extends must name a label set that extends nothing.")
        inherited, flags = _classes(base.get("classes"), f"{where}: label_sets.{spec['extends']}")
        classes.update(inherited)
        grounds |= flags["ground"]
        flats |= flags["flat"]
        movers |= flags["moving"]
        egos |= flags["ego"]
    own, own_flags = _classes(spec["classes"], ctx)
    classes.update(own)
    grounds = (grounds - set(own)) | own_flags["ground"]
    flats = (flats - set(own)) | own_flags["flat"]
    movers = (movers - set(own)) | own_flags["moving"]
    egos = (egos - set(own)) | own_flags["ego"]
    lookup = np.full(_OUT_OF_RANGE + 1, default.reflectance, dtype=np.float32)
    known = np.zeros(_OUT_OF_RANGE + 1, dtype=bool)
    order = {m: i for i, m in enumerate(materials)}
    material_of = np.full(_OUT_OF_RANGE + 1, order[default.name], dtype=np.int16)
    ground = np.zeros(_OUT_OF_RANGE + 1, dtype=bool)
    ground[sorted(grounds)] = True
    for class_id, (class_name, material) in classes.items():
        if material not in materials:
            raise ConfigError(
                f"{ctx}: class {class_id} ({class_name}) maps to unknown material "
                f"'{material}'; defined materials: {', '.join(sorted(materials))}."
            )
        lookup[class_id] = materials[material].reflectance
        known[class_id] = True
        material_of[class_id] = order[material]
    for table in (lookup, known, material_of, ground):
        table.flags.writeable = False
    return _LabelSet(name, bool(spec["instance_bits"]), classes, lookup, known, material_of,
                     ground, frozenset(flats), frozenset(movers), frozenset(egos))  # fmt: skip


CLASS_FLAGS = ("ground", "flat", "moving", "ego")  # optional true/false keys of a class


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
            entry, {"name", "material"}, f"{ctx}.classes.{class_id}",
            optional=frozenset(CLASS_FLAGS),
        )  # fmt: skip
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
