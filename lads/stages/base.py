"""The Stage protocol."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from lads.frame import Frame


class Stage(Protocol):
    """A transform of one frame. Never does I/O; all randomness comes from `rng`.

    Attributes:
        name: the stage name in pipeline files; also part of the rng identity.
        version: bumped whenever the stage's output bytes change for the same input.
    """

    name: str
    version: str

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame: ...
