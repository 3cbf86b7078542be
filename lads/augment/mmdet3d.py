"""mmdetection3d 1.x glue: `LadsCorruption`, a data-pipeline transform (docs/augment.md §2.2).

Importing this module registers the transform under the name "LadsCorruption" in
mmdet3d's TRANSFORMS registry when mmdet3d is installed, else in mmengine's root TRANSFORMS
(which mmdet3d's registry falls back to); a config then needs two lines:

    custom_imports = dict(imports=["lads.augment.mmdet3d"], allow_failed_imports=False)
    dict(type="LadsCorruption", corruption="snow", severity="moderate", sensor="hdl32e")

The transform follows mmcv's BaseTransform contract (`transform(results) -> results`) and
updates `points` (a BasePoints such as LiDARPoints, a tensor or an array), and
`pts_semantic_mask` / `pts_instance_mask` when present; boxes are left as they are.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from lads.augment.core import Corruption
from lads.augment.pseudo_labels import PSEUDO_LABEL_SET, vehicle_labels
from lads.errors import AugmentInputError

try:  # mmcv's base class when it is installed; the contract is the same without it.
    from mmcv.transforms import BaseTransform as _Base
except ImportError:  # pragma: no cover - depends on the environment

    class _Base:  # type: ignore[no-redef]
        """mmcv's BaseTransform contract: calling the transform runs `transform`."""

        def __call__(self, results: dict[str, Any]) -> dict[str, Any] | None:
            return self.transform(results)  # type: ignore[attr-defined, no-any-return]


# Keys of mmdet3d's results dict this transform reads and writes.
POINTS_KEY, SEMANTIC_KEY, INSTANCE_KEY = "points", "pts_semantic_mask", "pts_instance_mask"
BOXES_KEY, BOX_CLASSES_KEY = "gt_bboxes_3d", "gt_labels_3d"


def sample_id_of(results: dict[str, Any]) -> str:
    """A stable id of the sample: `sample_idx`, else the LiDAR file's name.

    Raises:
        AugmentInputError: the results name neither.
    """
    if results.get("sample_idx") is not None:
        return str(results["sample_idx"])
    path = (results.get("lidar_points") or {}).get("lidar_path") or results.get("lidar_path")
    if path:
        return os.path.basename(str(path))
    raise AugmentInputError(
        "LadsCorruption: the results dict has no 'sample_idx' and no LiDAR path, so the "
        "corruption cannot be tied to the sample; put it after LoadPointsFromFile."
    )


class LadsCorruption(_Base):  # type: ignore[misc]
    """Corrupt `results['points']` and its masks (arguments as `lads.augment.Corruption`).

    Args:
        corruption, severity, sensor, dataset, particle_label, ring_column, seed, **params:
            as `Corruption`; mmdet3d's remapped masks need `particle_label` (e.g. the
            ignore index) rather than `dataset`.
        probability: share of samples corrupted (drawn from the sample's generator).
        vehicle_classes: for detection data without point masks: the `gt_labels_3d` values
            of vehicle boxes; incomplete echo then finds the vehicles' points inside those
            boxes (`gt_bboxes_3d`: gravity_center, dims, yaw).
    """

    def __init__(
        self,
        corruption: str,
        probability: float = 1.0,
        vehicle_classes: list[int] | None = None,
        **options: Any,
    ) -> None:
        if not 0.0 <= probability <= 1.0:
            raise AugmentInputError(f"LadsCorruption: probability {probability}; expected [0, 1].")
        self.vehicle_classes = None if vehicle_classes is None else frozenset(vehicle_classes)
        if self.vehicle_classes is not None:
            options.setdefault("dataset", PSEUDO_LABEL_SET)
        self.corruption = Corruption(corruption, **options)
        self.probability = float(probability)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        """Draw the next epoch's corruptions (workers see it when they are started)."""
        self.epoch = int(epoch)

    def transform(self, results: dict[str, Any]) -> dict[str, Any]:
        sample_id = sample_id_of(results)
        rng = self.corruption.rng(sample_id, self.epoch)
        if self.probability < 1.0 and rng.random() >= self.probability:
            return results
        holder = results[POINTS_KEY]
        tensor = getattr(holder, "tensor", holder)
        is_tensor = hasattr(tensor, "detach")
        points = tensor.detach().cpu().numpy() if is_tensor else np.asarray(tensor)
        labels, instance = results.get(SEMANTIC_KEY), results.get(INSTANCE_KEY)
        given = labels
        if labels is None and self.vehicle_classes is not None:
            labels = self._box_labels(results, points)
        out = self.corruption.apply(points, labels, instance, rng, sample_id)
        new = out.points
        if is_tensor:
            new = tensor.new_tensor(new)
        results[POINTS_KEY] = holder.new_point(new) if hasattr(holder, "new_point") else new
        if given is not None:
            results[SEMANTIC_KEY] = out.labels
        if instance is not None:
            results[INSTANCE_KEY] = out.instance
        results["lads_outcome"] = out.info.outcome
        return results

    def _box_labels(self, results: dict[str, Any], points: np.ndarray) -> np.ndarray:
        """SemanticKITTI ids from the boxes: car inside boxes of `vehicle_classes`."""
        boxes = results.get(BOXES_KEY)
        if boxes is None:
            return vehicle_labels(points[:, :3], np.zeros((0, 7)), [])
        centre = np.asarray(boxes.gravity_center)
        layout = np.column_stack([centre, np.asarray(boxes.dims), np.asarray(boxes.yaw)])
        classes = np.asarray(results.get(BOX_CLASSES_KEY, np.zeros(len(layout), int)))
        vehicles = self.vehicle_classes or frozenset()
        return vehicle_labels(points[:, :3], layout, [int(c) in vehicles for c in classes])

    def __repr__(self) -> str:
        return f"LadsCorruption({self.corruption!r}, probability={self.probability})"


def register() -> str | None:
    """Register LadsCorruption in mmdet3d's TRANSFORMS, else mmengine's; returns the
    registry's scope, or None when neither package is installed."""
    import importlib

    for module in ("mmdet3d.registry", "mmengine.registry"):
        try:
            registry: Any = importlib.import_module(module).TRANSFORMS
        except ImportError:
            continue
        registry.register_module(name="LadsCorruption", module=LadsCorruption, force=True)
        return str(registry.scope)
    return None


REGISTERED_SCOPE = register()
