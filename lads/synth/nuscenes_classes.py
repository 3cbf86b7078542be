"""The nuScenes-lidarseg class list and the SemanticKITTI -> lidarseg map that synthetic
nuScenes data is labelled with (lads/synth/nuscenes_lidarseg.yaml, docs/formats.md §2)."""

from __future__ import annotations

import functools
import importlib.resources
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from lads.errors import ConfigError
from lads.physics.materials import class_materials
from lads.synth.parts import SEMANTICKITTI_OF_PART

CLASSES_FILE = "nuscenes_lidarseg.yaml"


@dataclass(frozen=True, slots=True)
class LidarsegClasses:
    """The lidarseg class list and the SemanticKITTI -> lidarseg map (nuscenes_lidarseg.yaml).

    Attributes:
        categories: the 32 class names; a class's `index` is its position.
        of_semantickitti: (65536,) uint8 lidarseg index per SemanticKITTI raw id (ids not
            listed map to 0 noise; every id the generator emits is listed).
    """

    categories: tuple[str, ...]
    of_semantickitti: npt.NDArray[np.uint8]

    def labels(self, semantickitti: npt.ArrayLike) -> npt.NDArray[np.uint8]:
        """(N,) uint8 lidarseg indices of SemanticKITTI labels (instance bits ignored)."""
        raw = np.asarray(semantickitti).astype(np.uint32) & np.uint32(0xFFFF)
        return self.of_semantickitti[raw]


@functools.cache
def lidarseg_classes() -> LidarsegClasses:
    """Load and check the shipped class table (cached).

    Raises:
        ConfigError: the YAML is malformed, the class list differs from the `nuscenes` label
            set of lads/physics/materials.yaml, a mapped name is not a class, or an id the
            generator emits is not mapped.
    """
    where = f"lads/synth/{CLASSES_FILE}"
    try:
        raw: Any = yaml.safe_load(
            importlib.resources.files("lads.synth").joinpath(CLASSES_FILE).read_text()
        )
        categories = tuple(str(c) for c in raw["categories"])
        mapping = {int(k): str(v) for k, v in raw["from_semantickitti"].items()}
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{where}: cannot read the class table ({exc}); fix the file.") from exc
    known = {i: name for i, (name, _) in class_materials("nuscenes").items()}
    problems = []
    if dict(enumerate(categories)) != known:
        problems.append(
            "categories differ from the nuscenes label set of lads/physics/materials.yaml "
            f"({len(categories)} vs {len(known)} classes)"
        )
    problems += [
        f"id {k} maps to unknown class '{v}'" for k, v in mapping.items() if v not in categories
    ]
    problems += [f"id {k} is outside 0..65535" for k in mapping if not 0 <= k <= 0xFFFF]
    emitted = sorted(set(SEMANTICKITTI_OF_PART.tolist()))
    problems += [f"generator id {s} is not mapped" for s in emitted if s not in mapping]
    if problems:
        raise ConfigError(f"{where}: " + "; ".join(problems) + ".")
    lut = np.zeros(0x10000, dtype=np.uint8)
    for k, v in mapping.items():
        lut[k] = categories.index(v)
    return LidarsegClasses(categories=categories, of_semantickitti=lut)
