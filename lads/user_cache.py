"""A per-user cache of values that are slow to compute and never change for given inputs.

Each build worker is a new process; without this, every worker recomputed the same tables
(the Mie extinction table took ~1.5 s per process) before its first frame. Entries are
`.npy` files named by a hash of everything the value depends on, written atomically, and
recomputed when missing or unreadable (callers check the shape they expect), so a stale
or damaged cache cannot change a result. Folder: $LADS_CACHE_DIR, else $XDG_CACHE_HOME/lads, else
~/.cache/lads; an unwritable folder only costs the recomputation.
"""

from __future__ import annotations

import hashlib
import io
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from lads.errors import LadsError
from lads.files import atomic_write

CACHE_ENV = "LADS_CACHE_DIR"


def cache_root() -> Path:
    """The cache folder (it may not exist yet)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "lads"


def cached_array(
    name: str, key: str, compute: Callable[[], npt.NDArray[np.float64]]
) -> npt.NDArray[np.float64]:
    """`compute()`, or the value it returned before for the same `name` and `key`.

    Args:
        name: a readable prefix of the file name, e.g. "mie-qext".
        key: everything the value depends on (inputs, library versions), as text.
        compute: the function that makes the value: a float64 array.

    Returns:
        The float64 array.
    """
    digest = hashlib.sha256(f"{name}\n{key}".encode()).hexdigest()[:24]
    path = cache_root() / f"{name}-{digest}.npy"
    try:
        value = np.load(path, allow_pickle=False)
        if value.dtype == np.float64:
            return value
    except (OSError, ValueError):
        pass
    value = np.asarray(compute(), dtype=np.float64)
    buffer = io.BytesIO()
    np.save(buffer, value, allow_pickle=False)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, buffer.getvalue())
    except (OSError, LadsError):
        pass  # a read-only home only costs the recomputation next time
    return value
