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

import numpy as np
import numpy.typing as npt
import yaml

from lads.errors import ConfigError, InputDataError
from lads.physics.materials_schema import (
    LABEL_SETS,
    MAX_CLASS_ID,
    OUT_OF_RANGE,
    LabelSet,
    Material,
    Table,
    parse_table,
)

MATERIALS_FILE = "materials.yaml"


class UnknownLabelWarning(UserWarning):
    """Labels without a class -> material entry were given the default reflectance."""


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


def reflectance_and_material_for_labels(
    labels: npt.ArrayLike, label_set: str
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]:
    """`reflectance_for_labels` and `material_index_for_labels` from one lookup of the
    points' classes (a learned intensity stage needs both for every frame).

    Raises:
        ConfigError, InputDataError: as `reflectance_for_labels`.
    """
    lset, ids = _classes_of(labels, label_set)
    return lset.lookup[ids], lset.material[ids].astype(np.int64)


def _classes_of(labels: npt.ArrayLike, label_set: str) -> tuple[LabelSet, npt.NDArray[np.intp]]:
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
    return ClassRoles(
        finished("clearcoat"),
        finished("retroreflective"),
        road_like,
        road_like | lset.flat,
        lset.moving,
        lset.ego,
    )


def class_ids(labels: npt.ArrayLike, label_set: str) -> npt.NDArray[np.int64]:
    """(N,) int64 semantic class of each label: label & 0xFFFF where the label set stores
    instance bits (materials.yaml, `has_instance_bits`), else the label itself."""
    arr = np.asarray(labels).astype(np.int64, copy=False)
    return arr & MAX_CLASS_ID if has_instance_bits(label_set) else arr


def has_instance_bits(label_set: str) -> bool:
    """Whether `label_set`'s stored labels carry an instance id above their low 16 bits
    (materials.yaml `instance_bits`; the class is then label & MAX_CLASS_ID).

    Raises:
        ConfigError: unknown label set.
    """
    return _label_set_of(label_set).instance_bits


def _label_set_of(label_set: str) -> LabelSet:
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
    ids = arr & MAX_CLASS_ID if instance_bits else np.minimum(arr, OUT_OF_RANGE)
    return ids.astype(np.intp, copy=False)


def _warn_unknown(lset: LabelSet, labels: npt.ArrayLike, unknown: npt.NDArray[np.bool_]) -> None:
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
def _table() -> Table:
    resource = importlib.resources.files("lads.physics").joinpath(MATERIALS_FILE)
    try:
        raw = yaml.safe_load(resource.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{MATERIALS_FILE}: cannot read YAML ({exc}).") from exc
    return parse_table(raw, MATERIALS_FILE)
