"""What run.json records about the software that made a tree."""

from __future__ import annotations

import importlib.metadata
import platform
import subprocess
from pathlib import Path

import lads

_LIBRARIES = ("numpy", "scipy", "numba", "zarr", "joblib", "miepython", "torch", "nuscenes-devkit")


def library_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in _LIBRARIES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def git_commit() -> str:
    """HEAD of the lads checkout (with '+dirty' when the work tree has changes), or 'unknown'."""
    repo = Path(lads.__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no", "--", "lads"],
            capture_output=True, text=True, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")
