"""OpenPCDet glue: a `DATA_AUGMENTOR.AUG_CONFIG_LIST` entry (docs/augment.md §2.1).

OpenPCDet's DataAugmentor builds its queue with `getattr(self, cfg.NAME)(config=cfg)`, so an
augmentation is a method of that class. `install()` adds `lads_corruption` to it; the
dataset config then lists

    - NAME: lads_corruption
      CORRUPTION: snow
      SEVERITY: moderate
      SENSOR: hdl64e

Other keys: SEED, PROBABILITY, DATASET, PARTICLE_LABEL, RING_COLUMN, EPOCH_KEY and PARAMS (a
dict of stage parameters). The entry corrupts `data_dict['points']` (N, 3 + C features,
x, y, z, intensity first) and keeps `gt_boxes`, `gt_names` and any other key; the sample is
named by `data_dict['frame_id']`. OpenPCDet's data_dict carries no point labels: incomplete
echo finds the vehicles through the boxes whose `gt_names` are vehicle classes, and wet ground
lies on the fitted ground (`lads.augment.pseudo_labels`).
"""

from __future__ import annotations

from functools import cache, partial
from typing import Any

import numpy as np

from lads.augment.core import Corruption, checked_probability
from lads.augment.pseudo_labels import PSEUDO_LABEL_SET, VEHICLE_NAMES, vehicle_labels
from lads.augment.shared_epoch import SharedEpoch
from lads.corruptions import corruption_spec
from lads.errors import AugmentInputError

# Config keys of an entry, mapped to `Corruption` arguments.
_KEYS = {
    "CORRUPTION": "corruption", "SEVERITY": "severity", "SENSOR": "sensor", "SEED": "seed",
    "DATASET": "dataset", "PARTICLE_LABEL": "particle_label", "RING_COLUMN": "ring_column",
}  # fmt: skip
_OWN_KEYS = {"NAME", "PROBABILITY", "PARAMS", "EPOCH_KEY"}
# The corruption that reads the vehicles from the boxes.
BOXED = "incomplete_echo"


class OpenPCDetCorruption:
    """One configured entry: called on a data_dict, returns it corrupted.

    Args:
        config: the entry (an EasyDict or a dict) with the keys above.

    Raises:
        AugmentInputError: unknown keys. ConfigError: as `Corruption`.
    """

    def __init__(self, config: Any) -> None:
        given = dict(config)
        unknown = sorted(set(given) - set(_KEYS) - _OWN_KEYS)
        if unknown:
            raise AugmentInputError(
                f"lads_corruption: unknown keys {unknown}; expected "
                f"{sorted(set(_KEYS) | _OWN_KEYS)}."
            )
        options = {_KEYS[k]: v for k, v in given.items() if k in _KEYS}
        for key in ("CORRUPTION", "SENSOR"):
            if key not in given:
                raise AugmentInputError(
                    f"lads_corruption: no {key} key; the entry needs CORRUPTION and SENSOR "
                    "(a profile of `lads profiles`, e.g. hdl64e)."
                )
        self.from_boxes = corruption_spec(str(options.get("corruption"))).name == BOXED
        if self.from_boxes:
            options.setdefault("dataset", PSEUDO_LABEL_SET)
        self.corruption = Corruption(**options, **dict(given.get("PARAMS") or {}))
        self.probability = checked_probability(given.get("PROBABILITY", 1.0), "lads_corruption")
        self.epoch_key = given.get("EPOCH_KEY", "epoch")
        self._epoch = _shared_epoch()  # `set_epoch` reaches it, in running workers too

    def __call__(self, data_dict: dict[str, Any]) -> dict[str, Any]:
        if "frame_id" not in data_dict:
            raise AugmentInputError(
                "lads_corruption: data_dict has no 'frame_id' to tie the corruption to the "
                "sample; OpenPCDet's datasets set it in __getitem__."
            )
        sample_id = str(data_dict["frame_id"])
        epoch = int(data_dict.get(self.epoch_key, self._epoch.get()))
        rng = self.corruption.rng(sample_id, epoch)
        if self.probability < 1.0 and rng.random() >= self.probability:
            return data_dict
        points = data_dict["points"]
        labels = None
        if self.from_boxes:
            labels = _box_labels(data_dict, points)
        out = self.corruption.apply(points, labels, None, rng, sample_id)
        data_dict["points"] = out.points
        return data_dict


def _box_labels(data_dict: dict[str, Any], points: np.ndarray) -> np.ndarray:
    """SemanticKITTI ids from the boxes: car inside the boxes whose `gt_names` are vehicles.

    Raises:
        AugmentInputError: boxes without one name each (their classes are unknown)."""
    boxes = np.asarray(data_dict.get("gt_boxes", np.zeros((0, 7))))
    names = list(data_dict.get("gt_names", []))
    if len(names) != len(boxes):
        raise AugmentInputError(
            f"lads_corruption: {len(boxes)} gt_boxes but {len(names)} gt_names; incomplete "
            "echo finds vehicles by the names of their boxes, so each box needs one."
        )
    return vehicle_labels(points[:, :3], boxes, [n in VEHICLE_NAMES for n in names])


@cache
def _shared_epoch() -> SharedEpoch:
    """The one epoch every entry this process configures reads (made on first use)."""
    return SharedEpoch()


def set_epoch(epoch: int) -> None:
    """Draw the next epoch's corruptions in every lads_corruption entry, in the DataLoader's
    running workers too: call it at the start of each epoch of the training loop, in the
    process that built the datasets (a data_dict's own `epoch` key takes precedence)."""
    _shared_epoch().set(epoch)


def lads_corruption(self: Any, data_dict: dict[str, Any] | None = None, config: Any = None) -> Any:
    """The DataAugmentor method: with no data_dict it returns the configured callable
    (OpenPCDet's convention), else it corrupts the data_dict."""
    if data_dict is None:
        return partial(_run, OpenPCDetCorruption(config))
    return OpenPCDetCorruption(config)(data_dict)


def _run(entry: OpenPCDetCorruption, data_dict: dict[str, Any]) -> dict[str, Any]:
    return entry(data_dict)


def install(augmentor_class: Any = None) -> Any:
    """Add `lads_corruption` to OpenPCDet's DataAugmentor (or the class given).

    Returns the class. Raises AugmentInputError when OpenPCDet is not installed and no class
    is given.
    """
    if augmentor_class is None:
        try:
            from pcdet.datasets.augmentor.data_augmentor import DataAugmentor
        except ImportError as exc:
            raise AugmentInputError(
                "lads.augment.openpcdet.install: OpenPCDet (pcdet) is not importable; install "
                "it, or pass your DataAugmentor class."
            ) from exc
        augmentor_class = DataAugmentor
    augmentor_class.lads_corruption = lads_corruption
    return augmentor_class
