"""mmdetection3d 1.x glue: `LadsCorruption`, a data-pipeline transform (docs/augment.md §2.2).

Importing this module registers the transform under the name "LadsCorruption" in
mmdet3d's TRANSFORMS registry when mmdet3d is installed, else in mmengine's root TRANSFORMS
(which mmdet3d's registry falls back to); a config then needs two lines:

    custom_imports = dict(imports=["lads.augment.mmdet3d"], allow_failed_imports=False)
    dict(type="LadsCorruption", corruption="snow", severity="moderate", sensor="hdl32e")

The transform follows mmcv's BaseTransform contract (`transform(results) -> results`) and
updates `points` (a BasePoints such as LiDARPoints, a tensor or an array), and
`pts_semantic_mask` / `pts_instance_mask` when present; boxes are left as they are.
`LadsEpochHook` (HOOKS, `custom_hooks = [dict(type="LadsEpochHook")]`) gives the runner's
epoch to the transforms before each training epoch, so each epoch draws new corruptions.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from lads.augment.core import Corruption, checked_probability
from lads.augment.pseudo_labels import PSEUDO_LABEL_SET, vehicle_labels
from lads.augment.shared_epoch import SharedEpoch
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
        severity: str | None = None,
        probability: float = 1.0,
        vehicle_classes: list[int] | None = None,
        **options: Any,
    ) -> None:
        self.probability = checked_probability(probability, "LadsCorruption")
        self.vehicle_classes = None if vehicle_classes is None else frozenset(vehicle_classes)
        if self.vehicle_classes is not None:
            options.setdefault("dataset", PSEUDO_LABEL_SET)
        self.corruption = Corruption(corruption, severity, **options)
        self._epoch = SharedEpoch()  # persistent workers read what set_epoch sets

    @property
    def epoch(self) -> int:
        """The epoch whose corruptions `transform` draws (`LadsEpochHook` sets the runner's)."""
        return self._epoch.get()

    def set_epoch(self, epoch: int) -> None:
        """Draw the next epoch's corruptions, in running workers too."""
        self._epoch.set(epoch)

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


def corruptions_in(dataset: Any) -> list[LadsCorruption]:
    """Every LadsCorruption in the pipelines of a dataset and the datasets it wraps
    (mmengine's ConcatDataset, RepeatDataset, ClassBalancedDataset, CBGS wrappers...)."""
    found: list[LadsCorruption] = []
    todo, seen = [dataset], set()
    while todo:
        node = todo.pop()
        if node is None or id(node) in seen:
            continue
        seen.add(id(node))
        transforms = getattr(getattr(node, "pipeline", None), "transforms", None) or []
        found += [t for t in transforms if isinstance(t, LadsCorruption)]
        todo += [getattr(node, "dataset", None), *(getattr(node, "datasets", None) or [])]
    return found


def set_epoch_of(dataset: Any, epoch: int) -> int:
    """Set `epoch` on every LadsCorruption of a dataset's pipelines; returns how many."""
    corruptions = corruptions_in(dataset)
    for corruption in corruptions:
        corruption.set_epoch(epoch)
    return len(corruptions)


def _epoch_hook() -> type | None:
    """`LadsEpochHook`, an mmengine hook; None without mmengine."""
    try:
        from mmengine.hooks import Hook
    except ImportError:  # pragma: no cover - depends on the environment
        return None

    class LadsEpochHook(Hook):  # type: ignore[misc]
        """Before each training epoch, give the runner's epoch to every LadsCorruption of
        the train dataloader's dataset, so each epoch draws new corruptions (config:
        `custom_hooks = [dict(type="LadsEpochHook")]`)."""

        def before_train_epoch(self, runner: Any) -> None:
            set_epoch_of(runner.train_dataloader.dataset, runner.epoch)

    return LadsEpochHook


LadsEpochHook = _epoch_hook()


def register() -> str | None:
    """Register LadsCorruption in mmdet3d's TRANSFORMS and LadsEpochHook in its HOOKS, else
    in mmengine's; returns the registry's scope, or None when neither package is installed."""
    import importlib

    for module in ("mmdet3d.registry", "mmengine.registry"):
        try:
            registries: Any = importlib.import_module(module)
        except ImportError:
            continue
        registries.TRANSFORMS.register_module(
            name="LadsCorruption", module=LadsCorruption, force=True
        )
        if LadsEpochHook is not None:
            registries.HOOKS.register_module(name="LadsEpochHook", module=LadsEpochHook, force=True)
        return str(registries.TRANSFORMS.scope)
    return None


REGISTERED_SCOPE = register()
