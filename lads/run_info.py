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


def own_checkout() -> Path | None:
    """The root of lads' own git checkout when lads runs from one (an editable install),
    else None: an installed lads may sit in a venv inside some other repository, whose
    commit says nothing about lads."""
    repo = Path(lads.__file__).resolve().parents[1]
    try:
        meta = (repo / "pyproject.toml").read_text()
    except OSError:
        return None
    if 'name = "lads"' not in meta or not (repo / ".git").exists():
        return None
    return repo


def git_commit() -> str | None:
    """HEAD of lads' own checkout (with '+dirty' when lads/ has uncommitted changes);
    None when lads is installed from a wheel (its version is then the whole story), or
    'unknown' when the checkout's git cannot be asked."""
    repo = own_checkout()
    if repo is None:
        return None
    try:
        head = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        # --no-optional-locks: a read-only look that never takes the index lock, so a build
        # killed at this moment cannot leave index.lock behind in the checkout.
        dirty = subprocess.run(
            [
                "git",
                "--no-optional-locks",
                "-C",
                str(repo),
                "status",
                "--porcelain",
                "--untracked-files=no",
                "--",
                "lads",
            ],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")
