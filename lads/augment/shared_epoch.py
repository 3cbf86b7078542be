"""An epoch number that a DataLoader's worker processes read while the main process sets it.

A loader adapter draws each sample's corruption from (seed, sample id, epoch). Workers get a
copy of the dataset when they start; persistent workers (`persistent_workers=True`, the
default of many mmdetection3d configs) keep that copy for the whole run, so an epoch kept as
a plain attribute would stay at the value they started with and every epoch would draw the
same corruptions. Kept in a shared-memory tensor, the value the main process sets is the one
every worker reads, whether the workers were forked or spawned (torch shares such tensors
when it pickles them).
"""

from __future__ import annotations

from typing import Any

from lads.errors import AugmentInputError


class SharedEpoch:
    """The current epoch (an int >= 0), in shared memory; torch is imported when one is made."""

    def __init__(self, epoch: int = 0) -> None:
        import torch

        self._value: Any = torch.zeros((), dtype=torch.int64).share_memory_()
        self.set(epoch)

    def get(self) -> int:
        return int(self._value)

    def __deepcopy__(self, memo: dict[int, Any]) -> SharedEpoch:
        """A copied transform or dataset keeps reading the same epoch (a deep copy of the
        tensor would leave shared memory)."""
        return self

    def set(self, epoch: int) -> None:
        """Raises AugmentInputError unless `epoch` is a whole number >= 0."""
        if isinstance(epoch, bool) or int(epoch) != epoch or epoch < 0:
            raise AugmentInputError(f"set_epoch({epoch!r}): expected a whole number >= 0.")
        self._value.fill_(int(epoch))
