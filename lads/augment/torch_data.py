"""PyTorch glue: a Dataset wrapper that corrupts each sample, and a worker-init helper
(docs/augment.md §2.3).

The corruption's randomness comes from (seed, sample id, epoch), so the same sample gets
the same corruption in epoch e whichever worker loads it, with any `num_workers`, persistent
workers included.
"""

from __future__ import annotations

import random
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from lads.augment.core import AugmentInfo, Corruption, checked_probability
from lads.augment.shared_epoch import SharedEpoch
from lads.errors import AugmentInputError


def _as_numpy(value: Any) -> tuple[np.ndarray, bool]:
    """(array, was_tensor); tensors are moved to the CPU without copying when possible."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy(), True
    return np.asarray(value), False


def _like(array: np.ndarray | None, was_tensor: bool) -> Any:
    if array is None or not was_tensor:
        return array
    return torch.from_numpy(np.ascontiguousarray(array))


class CorruptedDataset(Dataset):  # type: ignore[type-arg]
    """A map-style dataset whose samples come back corrupted.

    Args:
        dataset: the wrapped dataset; its samples are dicts (or tuples / lists) holding the
            points (N, C) as numpy arrays or tensors, and optionally per-point labels and
            instance ids.
        corruption: the `lads.augment.Corruption` to apply.
        points_key, labels_key, instance_key: where the sample holds them (dict keys, or
            positions for tuples); labels_key / instance_key None when absent.
        id_key: where the sample holds a stable id (e.g. a file path); None uses the
            dataset index, which is stable as long as the dataset's order is.
        info_key: if given, the sample gets the `AugmentInfo` under this key (dict samples
            only; collate functions must then accept it).
        probability: share of samples corrupted; the choice also comes from the sample's
            generator, so it too is reproducible.
    """

    def __init__(
        self,
        dataset: Any,
        corruption: Corruption,
        *,
        points_key: str | int = "points",
        labels_key: str | int | None = None,
        instance_key: str | int | None = None,
        id_key: str | int | None = None,
        info_key: str | None = None,
        probability: float = 1.0,
    ) -> None:
        self.dataset = dataset
        self.corruption = corruption
        self.keys = (points_key, labels_key, instance_key)
        self.id_key = id_key
        self.info_key = info_key
        self.probability = checked_probability(probability, "CorruptedDataset")
        self._epoch = SharedEpoch()  # persistent workers read what set_epoch sets

    @property
    def epoch(self) -> int:
        """The epoch whose corruptions `__getitem__` draws."""
        return self._epoch.get()

    def set_epoch(self, epoch: int) -> None:
        """Draw the next epoch's corruptions: call it before iterating the DataLoader for that
        epoch (its workers, persistent or not, then read it)."""
        self._epoch.set(epoch)

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int) -> Any:
        sample = self.dataset[index]
        sample_id = index if self.id_key is None else _field(sample, self.id_key, "id_key")
        rng = self.corruption.rng(str(sample_id), self.epoch)
        if self.probability < 1.0 and rng.random() >= self.probability:
            return sample
        names = ("points_key", "labels_key", "instance_key")
        arrays = [
            None if k is None else _as_numpy(_field(sample, k, name))
            for k, name in zip(self.keys, names, strict=True)
        ]
        points, labels, instance = (None if a is None else a[0] for a in arrays)
        result = self.corruption.apply(points, labels, instance, rng, str(sample_id))  # type: ignore[arg-type]
        new = (result.points, result.labels, result.instance)
        return self._put(sample, arrays, new, result.info)

    def _put(
        self,
        sample: Any,
        arrays: Sequence[tuple[np.ndarray, bool] | None],
        new: tuple[Any, Any, Any],
        info: AugmentInfo,
    ) -> Any:
        """The sample with the corrupted arrays in place, as tensors where they were."""
        out: Any = dict(sample) if isinstance(sample, Mapping) else list(sample)
        for key, value, given in zip(self.keys, new, arrays, strict=True):
            if key is not None and given is not None:
                out[key] = _like(value, given[1])
        if self.info_key is not None and isinstance(out, dict):
            out[self.info_key] = info
        if isinstance(sample, Mapping):
            return out
        # A named tuple takes its fields as arguments; a tuple or list takes one iterable.
        return type(sample)(*out) if hasattr(sample, "_fields") else type(sample)(out)


def _field(sample: Any, key: str | int, option: str) -> Any:
    """sample[key]; AugmentInputError naming the CorruptedDataset option when it is absent."""
    try:
        return sample[key]
    except (KeyError, IndexError, TypeError) as exc:
        kind = type(sample).__name__
        raise AugmentInputError(
            f"CorruptedDataset: the wrapped dataset's sample ({kind}) has no {key!r}, the "
            f"{option}; pass the key or index under which the sample holds it."
        ) from exc


def worker_init_fn(worker_id: int) -> None:
    """DataLoader `worker_init_fn`: one compute thread per worker (workers already run in
    parallel; more threads only oversubscribe the cores), and Python's and numpy's global
    generators seeded from the worker's torch seed for any other augmentation the user runs.
    lads corruptions do not need it: their randomness comes from the sample's identity."""
    torch.set_num_threads(1)
    seed = torch.initial_seed() % 2**32
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 - seeding the legacy global for user code is the point


__all__ = ["AugmentInfo", "CorruptedDataset", "worker_init_fn"]
