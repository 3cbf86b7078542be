"""Per-item random generators derived from the item's identity, never from shared state.

The same (root seed, dataset, relative path, variant, stage) always gives the same stream, so
output bytes do not depend on job count, order, process or backend. Python's `hash()` is
salted per process and is never used.
"""

from __future__ import annotations

import hashlib

import numpy as np


def seed_entropy(root_seed: int, item_id: str, variant: str, stage: str) -> list[int]:
    """The SeedSequence entropy for one (item, variant, stage): root seed + 4 uint32 words.

    The words are the first 16 bytes of SHA-256("item_id|variant|stage"), little-endian.
    """
    digest = hashlib.sha256(f"{item_id}|{variant}|{stage}".encode()).digest()
    words = np.frombuffer(digest[:16], dtype="<u4")
    return [int(root_seed), *(int(w) for w in words)]


def rng_for(root_seed: int, item_id: str, variant: str, stage: str) -> np.random.Generator:
    """numpy Generator for one stage of one item of one variant."""
    return np.random.default_rng(
        np.random.SeedSequence(seed_entropy(root_seed, item_id, variant, stage))
    )


def augment_rng(
    seed: int, sample_id: str | int, epoch: int, corruption: str
) -> np.random.Generator:
    """numpy Generator for one corruption of one training sample in one epoch.

    The same (seed, sample id, epoch, corruption) gives the same stream in any data-loader
    worker, so a training run is reproducible whatever the worker count; `epoch` changes the
    draw from one epoch to the next.
    """
    return rng_for(int(seed), f"augment:{sample_id}", f"epoch:{int(epoch)}", corruption)
