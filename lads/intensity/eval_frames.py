"""Real frames of a training config's roles as evaluation frames (held-out and validation).

A leaf of `lads.intensity`: the training loop (`selection`) and the CLI (`commands`) both read
frames through it, so neither imports the other.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import numpy.typing as npt

from lads.intensity.cache import read_domain_frame
from lads.intensity.evaluate import EvalFrame
from lads.intensity.train_config import DomainSpec


def frames_of(frames: list[tuple[str, DomainSpec, str]], kind: str) -> list[Any]:
    """EvalFrames of (tag, dataset, frame) triples of a real role (`cache.role_split`);
    frames of an `also` dataset are named "<tag>:<frame>"."""
    out = []
    for tag, domain, rel in frames:
        d = read_domain_frame(domain, rel, weather_model=kind == "weather")
        out.append(
            EvalFrame(
                name=f"{tag}:{rel}" if tag else rel,
                xyz=d.frame.xyz,
                intensity=d.frame.intensity,
                profile=d.profile,
                # Every reader's labels are integer class ids (Frame types them generically).
                labels=cast("npt.NDArray[np.integer[Any]] | None", d.frame.labels),
                label_set=d.label_set,
                ring=d.ring,
                particle=d.particle,
                extinction_per_m=d.extinction_per_m,
            )
        )
    return out
