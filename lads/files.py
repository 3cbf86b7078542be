"""Atomic writes and sha256 of files: the only way lads puts bytes on disk."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import os
import secrets
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lads.errors import OutputWriteError

TMP_SUFFIX = ".lads-tmp"
# Temp files carry the writing process's pid and a random token: parallel writers of one
# build never share one, and a temp file always names the run that made it.
_TOKEN = secrets.token_hex(4)


def tmp_name(path: Path) -> Path:
    """The temp file `atomic_write` uses for `path`, owned by this process."""
    return path.with_name(f"{path.name}.{os.getpid()}-{_TOKEN}{TMP_SUFFIX}")


def write_error(path: Path, exc: OSError) -> OutputWriteError:
    """An OutputWriteError saying in words what stopped a write to `path` and what to do."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        what = "no space left on its device (disk or quota full)"
        todo = "free space there, then run the same command again: it resumes where it stopped"
    elif exc.errno == errno.EROFS:
        what, todo = "the file system is read-only", "choose a writable --out"
    elif exc.errno in (errno.EACCES, errno.EPERM):
        what, todo = "permission denied", "choose an --out you may write to, or fix its rights"
    else:
        what, todo = exc.strerror or str(exc), "check the output folder and run again"
    return OutputWriteError(f"{path}: cannot write: {what}; {todo}.")


def make_folder(path: Path) -> None:
    """Create the folder `path` (and its parents) or raise OutputWriteError saying in words
    why it cannot be (a file in the way, no rights, a full or read-only disk)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputWriteError(f"{path}: is a file, not a folder; choose another path.") from None
    except NotADirectoryError:
        raise OutputWriteError(
            f"{path}: a part of the path is a file, not a folder; choose another path."
        ) from None
    except OSError as exc:
        raise write_error(path, exc) from exc


def _atomically(path: Path, fill: Callable[[Path], object]) -> None:
    """Make `path` by filling a temp file and renaming it; a failure leaves no temp file.
    Whatever `fill` returns is ignored."""
    tmp = tmp_name(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fill(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise write_error(path, exc) from exc


def atomic_write(path: Path, payload: bytes) -> None:
    """Write `payload` to `path` via a temp file in the same folder and os.replace.

    A crash leaves either the old file or the new one, never a torn file.

    Raises:
        OutputWriteError: disk full, read-only file system, permission denied (no temp file
            is left behind).
    """
    _atomically(Path(path), lambda tmp: tmp.write_bytes(payload))


def atomic_copy(source: Path, target: Path) -> None:
    """Copy a file byte for byte, atomically (temp file + rename); errors as atomic_write.
    The source must be readable (the caller checks)."""
    _atomically(Path(target), lambda tmp: shutil.copyfile(source, tmp))


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
    """Delete temp files left by killed runs under `root`; returns how many. Call it only
    while holding the output's lock (`lads.lock`): then no other run is writing there."""
    count = 0
    for tmp in root.rglob(f"*{TMP_SUFFIX}"):
        tmp.unlink(missing_ok=True)
        count += 1
    return count
