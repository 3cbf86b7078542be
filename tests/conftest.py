"""Shared fixtures: real scans from ../shared/data and a small synthetic street frame.

Real-data tests: every test under tests/realdata/, marked `realdata`, or using the
`shared_data` fixture (directly or through `real_tree`, `kitti_frame`, ...). Where
../shared/data is absent (a bare clone) they are skipped, and the summary says so in one line.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from benchmarks.common import SHARED_DATA
from lads.sensors.profile import SensorProfile
from lads.synth import synth_frame

KITTI_VELODYNE = "semantickitti/sequences/00/velodyne"
KITTI_FRAMES = (0, 1, 2)


def _needs_real_data(item: pytest.Item) -> bool:
    return (
        "shared_data" in getattr(item, "fixturenames", ())
        or item.get_closest_marker("realdata") is not None
        or "realdata" in Path(str(item.path)).parts
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    real = [item for item in items if _needs_real_data(item)]
    config.stash[_REAL_COUNT] = len(real)
    for item in real:
        item.add_marker(pytest.mark.realdata)
        if not SHARED_DATA.is_dir():
            item.add_marker(pytest.mark.skip(reason=f"real data: {SHARED_DATA} not found"))


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    n = config.stash.get(_REAL_COUNT, 0)
    if SHARED_DATA.is_dir():
        line = f"real-data tests: {n} selected, reading {SHARED_DATA}"
    else:
        line = (
            f"real-data tests: {n} SKIPPED: {SHARED_DATA} not found (a clone without the "
            "shared/ folder beside it); every other test ran"
        )
    terminalreporter.write_sep("-", line)


_REAL_COUNT = pytest.StashKey[int]()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data next to the repository; the test is skipped when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA}")
    return SHARED_DATA


@functools.lru_cache(maxsize=8)
def _read_kitti(path: Path) -> tuple[np.ndarray, np.ndarray]:
    points = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
    xyz, intensity = np.ascontiguousarray(points[:, :3]), np.ascontiguousarray(points[:, 3])
    xyz.flags.writeable = False
    intensity.flags.writeable = False
    return xyz, intensity


@pytest.fixture(scope="session")
def kitti_frame(shared_data):
    """Loader: kitti_frame(i) -> (xyz (N, 3) float32, intensity (N,) float32 in [0, 0.99]).

    i in 0..2 picks SemanticKITTI sequence 00, velodyne/00000i.bin (read-only arrays, cached).
    """

    def load(i: int) -> tuple[np.ndarray, np.ndarray]:
        if i not in KITTI_FRAMES:
            raise ValueError(f"frame {i}: only {KITTI_FRAMES} are in the shared sample")
        path = shared_data / KITTI_VELODYNE / f"{i:06d}.bin"
        if not path.is_file():
            pytest.skip(f"{path} not found")
        return _read_kitti(path)

    return load


def street_frame(
    profile: SensorProfile, *, azimuths: int = 720, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """One sweep of lads' synthetic street (`lads.synth`, the project's one ray caster) for
    `profile`, with `azimuths` beams per channel.

    Returns:
        xyz (N, 3) float32 and intensity (N,) float32 in the profile's encoding.
    """
    frame = synth_frame(profile, frames=1, seed=seed, index=0, azimuth_bins=azimuths)
    return frame.xyz, frame.intensity


# Dataset trees for reader and builder tests (tests/trees.py).


@pytest.fixture
def synthetic_tree(tmp_path):
    """synthetic_tree(name, **kwargs) -> root of a fresh synthetic tree in tmp_path.

    name is a reader name ("semantickitti", "wads", "voxelscape", "radiate", "nuscenes");
    kwargs go to the matching `tests.trees.synthetic_<name>` builder.
    """
    from tests import trees

    def build(name: str, **kwargs) -> Path:
        builder = getattr(trees, f"synthetic_{name.replace('-', '_')}")
        return builder(tmp_path / f"synthetic_{name}", **kwargs)

    return build


@pytest.fixture
def real_tree(shared_data, tmp_path):
    """real_tree(name) -> root of a tmp tree of symlinks to the real samples in ../shared/data.

    name: "semantickitti", "wads", "radiate" or "nuscenes" (see `tests.trees.real_<name>`).
    Skipped when ../shared/data is absent.
    """
    from tests import trees

    def build(name: str) -> Path:
        return getattr(trees, f"real_{name}")(tmp_path / f"real_{name}")

    return build
