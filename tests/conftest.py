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
    """A ray-cast street for `profile`: road plane, two facades, two end walls, open sky.

    The sensor sits 1.73 m above a flat road (z = -1.73 m); facades at y = +-9 m (up to
    12 m high) run from x = -70 to 70 m, where end walls close the street; upward beams
    that leave over the facades return nothing (open sky). Ranges span ~4-70 m. Intensities
    are a per-point reflectivity (road 0.05-0.25, walls 0.05-0.6, a few stored zeros)
    encoded in the profile's intensity encoding.

    Returns:
        xyz (N, 3) float32 and intensity (N,) float32, N ~ channels * azimuths * 0.8.
    """
    rng = np.random.default_rng(seed)
    el = np.radians(np.asarray(profile.elevation_deg))[:, None]
    az = np.linspace(-np.pi, np.pi, azimuths, endpoint=False)[None, :]
    el, az = np.broadcast_arrays(el, az)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    d = d.reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(d[:, 2] < 0, -1.73 / d[:, 2], np.inf)
        t_facade = np.where(d[:, 1] != 0, 9.0 / np.abs(d[:, 1]), np.inf)
        t_end = np.where(d[:, 0] != 0, 70.0 / np.abs(d[:, 0]), np.inf)
    t = np.minimum(np.minimum(t_ground, t_facade), t_end)
    hit = d * t[:, None]
    on_wall = t < t_ground
    valid = np.isfinite(t) & (hit[:, 2] < 12.0) & (t < 100.0)
    rho = np.where(on_wall, rng.uniform(0.05, 0.6, t.size), rng.uniform(0.05, 0.25, t.size))
    rho[rng.random(t.size) < 0.03] = 0.0
    intensity = profile.intensity.from_reflectivity(rho)
    return hit[valid].astype(np.float32), intensity[valid]


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
