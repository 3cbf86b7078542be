"""One writer per output tree: an exclusive lock on `OUT/.lads-lock` for a build (and for
`lads verify --regenerate`, which rebuilds items of the tree).

The lock is a `flock` on the lock file, so the kernel releases it when its holder exits or
dies: a crashed build never leaves a lock that blocks the next one. The file records its
holder (pid, host, start time, command) for the message a second build gets. The lock is
taken on the file's inode and the path is checked to still name it, so removing the file at
release cannot let two holders in.

File systems without `flock` (some network and FUSE mounts) fall back to the file's
existence: created exclusively, removed at release; a file left by a dead process on the
same host (its pid gone, or reused by another process) is taken over, one left from another
host is reported with the command that removes it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lads.errors import BuildError

LOCK_NAME = ".lads-lock"
POLL_S = 2.0
# A holder that has not written its record yet (or a `holder` probe) is retried this often,
# this far apart, before the lock counts as held by an unnamed process.
UNNAMED_RETRIES, UNNAMED_RETRY_S = 5, 0.05


class OutputLockedError(BuildError):
    """Another lads process holds the output tree."""


@dataclass(frozen=True, slots=True)
class Lock:
    path: Path
    fd: int
    flock: bool


def _process_start(pid: int) -> str | None:
    """Start time of a process in clock ticks since boot (Linux), None where unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[19]


def _owner(purpose: str) -> dict[str, Any]:
    pid = os.getpid()
    return {
        "pid": pid,
        "host": socket.gethostname(),
        "purpose": purpose,
        "started": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "process_start": _process_start(pid),
        "command": " ".join(sys.argv)[:300],
    }


def _read_owner(fd: int) -> dict[str, Any]:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        data = json.loads(os.read(fd, 65536) or b"{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _write_owner(fd: int, purpose: str) -> None:
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, json.dumps(_owner(purpose), sort_keys=True).encode())
    os.fsync(fd)


def _dead_here(owner: dict[str, Any]) -> bool:
    """The holder ran on this host and is gone (or its pid now belongs to another process)."""
    if owner.get("host") != socket.gethostname() or not isinstance(owner.get("pid"), int):
        return False
    try:
        os.kill(owner["pid"], 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        pass
    started = owner.get("process_start")
    return started is not None and _process_start(owner["pid"]) not in (None, started)


def describe(owner: dict[str, Any]) -> str:
    if not owner:
        return "a lads process (the lock file names no holder)"
    return (
        f"lads {owner.get('purpose', '?')} (pid {owner.get('pid', '?')} on host "
        f"{owner.get('host', '?')}, started {owner.get('started', '?')}: "
        f"{owner.get('command', '?')})"
    )


def _try_acquire(path: Path, purpose: str) -> Lock | dict[str, Any]:
    """One attempt: the Lock, or the holder's record when another process holds it."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        created = True
    except FileExistsError:
        try:
            fd = os.open(path, os.O_RDWR)
        except FileNotFoundError:  # released between the two calls: try again
            return {"retry": True}
        created = False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        owner = _read_owner(fd)
        os.close(fd)
        return owner
    except OSError as exc:
        if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
            os.close(fd)
            raise
        return _existence_lock(path, fd, created, purpose)
    try:
        same = os.fstat(fd).st_ino == os.stat(path).st_ino
    except FileNotFoundError:
        same = False
    if not same:  # the holder removed the file while we waited on its inode
        os.close(fd)
        return {"retry": True}
    _write_owner(fd, purpose)
    return Lock(path, fd, flock=True)


def _existence_lock(path: Path, fd: int, created: bool, purpose: str) -> Lock | dict[str, Any]:
    """Fallback without flock: whoever created the file holds the lock."""
    if created:
        _write_owner(fd, purpose)
        return Lock(path, fd, flock=False)
    owner = _read_owner(fd)
    os.close(fd)
    if _dead_here(owner):
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        return {"retry": True}
    return owner


def acquire(out_root: Path, purpose: str, *, wait: bool = False) -> Lock:
    """Take the lock of `out_root` (which must exist) for `purpose`, e.g. "build".

    Raises:
        OutputLockedError: another process holds it (and `wait` is False); the message names
            the holder.
        BuildError: the lock file cannot be written (read-only or full output).
    """
    path = Path(out_root) / LOCK_NAME
    unnamed = 0
    while True:
        try:
            got = _try_acquire(path, purpose)
        except OSError as exc:
            raise BuildError(
                f"{path}: cannot create the output's lock file ({exc.strerror or exc}); --out "
                "must be a writable folder with free space."
            ) from exc
        if isinstance(got, Lock):
            return got
        if got.get("retry"):
            continue
        if not got and unnamed < UNNAMED_RETRIES:
            unnamed += 1
            time.sleep(UNNAMED_RETRY_S)
            continue
        if not wait:
            hint = (
                ""
                if got.get("host") in (None, socket.gethostname())
                else f" If that machine crashed, delete {path} and run again."
            )
            raise OutputLockedError(
                f"{out_root}: {describe(got)} is writing this tree; one lads process per output "
                f"at a time. Wait for it to finish, or pass --wait to queue behind it.{hint}"
            )
        time.sleep(POLL_S)


def release(lock: Lock) -> None:
    """Remove the lock file, then let go of it (in that order: see the module doc)."""
    with contextlib.suppress(FileNotFoundError):
        lock.path.unlink()
    os.close(lock.fd)


@contextlib.contextmanager
def output_lock(out_root: Path, purpose: str, *, wait: bool = False) -> Iterator[Lock]:
    """`acquire` ... `release` around a block."""
    lock = acquire(out_root, purpose, wait=wait)
    try:
        yield lock
    finally:
        release(lock)


def holder(out_root: Path) -> dict[str, Any] | None:
    """The record of a live holder of `out_root`'s lock, or None when nobody holds it."""
    path = Path(out_root) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _read_owner(fd) or {}
    except OSError:  # no flock here: the file's existence is the lock
        owner = _read_owner(fd)
        return None if _dead_here(owner) else owner
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
