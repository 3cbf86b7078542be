"""Which frames of a real domain train, choose and judge a model.

A training config splits a target (or weather source) domain into three disjoint sets,
each a list of shell patterns matched against the frame names (the reader's item relpaths,
or the file paths under a folder of bare nuScenes scans):

    train        the only frames the weights and the fitted baselines see
    validation   the only frames that choose loss weights, steps and architecture
    test         scored once per reported model; they choose nothing

Frames 0.1 s apart show the same scene, so a split must be made by place: by sequence, or by
distance along the route, never by alternating neighbouring frames. Domains without a
split train on all their frames (synthetic sources, sources in weather).

A domain may draw its frames from several roots (`root: [a, b]`): they are merged into one
view, a folder of symbolic links under the system's temp folder, so frame names stay the
relpaths of the dataset's own layout. Two roots holding the same relpath are an error.
"""

from __future__ import annotations

import fnmatch
import hashlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from lads.errors import ConfigError

SPLITS = ("train", "validation", "test")
_DONE = ".lads-merged"


def select(names: Iterable[str], patterns: Iterable[str]) -> list[str]:
    """The names that match any of the shell patterns, in the order given."""
    pats = list(patterns)
    return [n for n in names if any(fnmatch.fnmatchcase(n, p) for p in pats)]


def split_frames(
    names: list[str], split: dict[str, tuple[str, ...]], where: str
) -> dict[str, list[str]]:
    """{split name: frames} of a domain's frame names.

    Without a split every frame trains. Each pattern must match at least one frame, and no
    frame may fall in two splits.

    Raises:
        ConfigError: an unknown split name, a pattern matching nothing, overlapping splits.
    """
    if not split:
        return {"train": list(names), "validation": [], "test": []}
    unknown = sorted(set(split) - set(SPLITS))
    if unknown:
        raise ConfigError(f"{where}: split names {unknown}; expected some of {list(SPLITS)}.")
    out: dict[str, list[str]] = {}
    for name in SPLITS:
        patterns = split.get(name, ())
        for pattern in patterns:
            if not select(names, [pattern]):
                raise ConfigError(
                    f"{where}: split.{name} pattern {pattern!r} matches no frame; frame names "
                    f"look like {names[:2]}."
                )
        out[name] = select(names, patterns)
    seen: dict[str, str] = {}
    for name in SPLITS:
        for frame in out[name]:
            if frame in seen:
                raise ConfigError(
                    f"{where}: frame {frame} is in both split.{seen[frame]} and split.{name}; "
                    "splits must be disjoint (and made by place, not by neighbouring frames)."
                )
            seen[frame] = name
    return out


def merged_view(roots: list[Path]) -> Path:
    """One folder presenting the files of every root at their own relpaths (symlinks),
    made once per set of roots under the temp folder and reused.

    Raises:
        ConfigError: a root is missing, or two roots hold the same relpath.
    """
    resolved = [Path(r).expanduser().resolve() for r in roots]
    for root in resolved:
        if not root.is_dir():
            raise ConfigError(f"{root}: dataset root not found; check the config's root list.")
    digest = hashlib.sha256("\n".join(map(str, resolved)).encode()).hexdigest()[:16]
    view = Path(tempfile.gettempdir()) / f"lads-merged-{digest}"
    if (view / _DONE).is_file():
        return view
    owner: dict[str, Path] = {}
    for root in resolved:
        for folder, _, files in os.walk(root, followlinks=True):
            for name in files:
                rel = (Path(folder) / name).relative_to(root).as_posix()
                if rel in owner:
                    raise ConfigError(
                        f"{rel} is in two dataset roots ({owner[rel]} and {root}); a merged "
                        "domain needs disjoint roots."
                    )
                owner[rel] = root
    for rel, root in owner.items():
        link = view / rel
        link.parent.mkdir(parents=True, exist_ok=True)
        if not link.is_symlink():
            link.symlink_to(root / rel)
    (view / _DONE).write_text("\n".join(map(str, resolved)) + "\n")
    return view
