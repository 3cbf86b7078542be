"""Voxelscape label codes for synthetic trees (lads/synth/voxelscape_ids.yaml, a stand-in)."""

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
from lads.synth.parts import SUBLABEL_OF_PART

IDS_FILE = "voxelscape_ids.yaml"


@dataclass(frozen=True, slots=True)
class VoxelscapeIds:
    """The stand-in code table, and per generator part its three Voxelscape labels.

    Attributes:
        classes: orig_labels code -> class name (32 classes).
        sublabels: _subl code -> (name, kitti_labels id).
        orig_of_part, subl_of_part: (parts,) int32 codes indexed by lads.synth.parts.Part.
        kitti_of_part: (parts,) uint32 kitti_labels id indexed by Part.
    """

    classes: dict[int, str]
    sublabels: dict[int, tuple[str, int]]
    orig_of_part: npt.NDArray[np.int32]
    subl_of_part: npt.NDArray[np.int32]
    kitti_of_part: npt.NDArray[np.uint32]


@functools.cache
def voxelscape_ids() -> VoxelscapeIds:
    """Load and check the shipped table (cached).

    Raises:
        ConfigError: the YAML is malformed, a sub-label's class (code // 10) or its
            kitti_label is unknown, or a generator part has no sub-label.
    """
    where = f"lads/synth/{IDS_FILE}"
    try:
        raw: Any = yaml.safe_load(
            importlib.resources.files("lads.synth").joinpath(IDS_FILE).read_text()
        )
        classes = {int(k): str(v) for k, v in raw["classes"].items()}
        sublabels = {
            int(k): (str(v["name"]), int(v["kitti_label"])) for k, v in raw["sublabels"].items()
        }
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{where}: cannot read the code table ({exc}); fix the file.") from exc
    known_kitti = set(class_materials("voxelscape"))
    problems = [
        f"sub-label {s} has no class {s // 10}" for s in sublabels if s // 10 not in classes
    ]
    problems += [
        f"sub-label {s}: kitti_label {k} is not a Voxelscape id"
        for s, (_, k) in sublabels.items()
        if k not in known_kitti
    ]
    problems += [
        f"generator sub-label {s} is missing"
        for s in set(SUBLABEL_OF_PART.tolist())
        if s not in sublabels
    ]
    if problems:
        raise ConfigError(f"{where}: " + "; ".join(problems) + ".")
    return VoxelscapeIds(
        classes=classes,
        sublabels=sublabels,
        orig_of_part=(SUBLABEL_OF_PART // 10).astype(np.int32),
        subl_of_part=SUBLABEL_OF_PART.astype(np.int32),
        kitti_of_part=np.array([sublabels[int(s)][1] for s in SUBLABEL_OF_PART], dtype=np.uint32),
    )
