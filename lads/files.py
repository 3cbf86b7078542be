"""Atomic writes and sha256 of files: the only way lads puts bytes on disk."""

from __future__ import annotations

import hashlib
import io
import os
import shutil
from pathlib import Path
from typing import Any

TMP_SUFFIX = ".lads-tmp"


def atomic_write(path: Path, payload: bytes) -> None:
    """Write `payload` to `path` via a temp file in the same folder and os.replace.

    A crash leaves either the old file or the new one, never a torn file; the temp name is
    per process so parallel writers never share one.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}{TMP_SUFFIX}")
    with open(tmp, "wb") as handle:
        handle.write(payload)
    os.replace(tmp, path)


def atomic_copy(source: Path, target: Path) -> None:
    """Copy a file byte for byte, atomically (temp file + rename)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f"{target.name}.{os.getpid()}{TMP_SUFFIX}")
    shutil.copyfile(source, tmp)
    os.replace(tmp, target)


def sha256_bytes(payload: bytes) -> str:
    return hashlib.sha256(payload).hexdigest()


def atomic_write_figure(fig: Any, path: Path, *, dpi: int) -> None:
    """Render a matplotlib figure to PNG and write it with `atomic_write`."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    atomic_write(Path(path), buffer.getvalue())


def sha256_file(path: Path) -> str:
    """Streaming sha256 hex digest of a file."""
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def remove_stray_temps(root: Path) -> int:
    """Delete temp files left by a killed run under `root`; returns how many."""
    count = 0
    for tmp in root.rglob(f"*{TMP_SUFFIX}"):
        tmp.unlink(missing_ok=True)
        count += 1
    return count
