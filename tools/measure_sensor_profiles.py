"""Measure the per-channel elevations shipped in lads/sensors/{hdl64e,hdl32e,wads64}.yaml.

Run from the repository root:  .venv/bin/python tools/measure_sensor_profiles.py [DATA_DIR]
DATA_DIR defaults to ../shared/data. Prints, per sensor, the elevation of every channel in
each frame, the per-channel median over the frames (the shipped table, rounded to 0.001
degree) and the vertical field of view with half a channel spacing of margin.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from lads.sensors.measure import (
    elevations_from_histogram,
    elevations_from_rings,
    elevations_from_scan_order,
    rings_from_scan_order,
    vertical_fov_deg,
)

KITTI = "semantickitti/sequences/00/velodyne/00000{}.bin"
NUSCENES = (
    "nuscenes/samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"
)
WADS = "wads/sequences/36/velodyne/04222{}.bin"
RADIATE = "radiate/tiny_foggy/velo_lidar/0000{}.csv"


def kitti_files(data: Path) -> list[Path]:
    return [data / KITTI.format(i) for i in range(3)]


def wads_files(data: Path) -> list[Path]:
    return [data / WADS.format(i) for i in (3, 4, 5)]


def measure_kitti(data: Path) -> np.ndarray:
    """(3, 64) elevations, one row per SemanticKITTI frame, by scan order."""
    scans = [np.fromfile(p, dtype=np.float32).reshape(-1, 4) for p in kitti_files(data)]
    return np.array([elevations_from_scan_order(s[:, :3], 64) for s in scans])


def measure_nuscenes(data: Path) -> np.ndarray:
    """(1, 32) elevations of the nuScenes keyframe from its ring column."""
    scan = np.fromfile(data / NUSCENES, dtype=np.float32).reshape(-1, 5)
    return elevations_from_rings(scan[:, :3], scan[:, 4].astype(np.int64), 32)[None]


def measure_wads(data: Path) -> np.ndarray:
    """(3, 64) elevations, one row per WADS frame, by elevation-histogram peaks."""
    scans = [np.fromfile(p, dtype=np.float32).reshape(-1, 4) for p in wads_files(data)]
    return np.array([elevations_from_histogram(s[:, :3], 64) for s in scans])


def measure_radiate(data: Path) -> np.ndarray:
    """(3, 32) elevations of the RADIATE HDL-32E frames (cross-check of hdl32e)."""
    rows = []
    for i in (18, 19, 20):
        scan = np.loadtxt(data / RADIATE.format(i), delimiter=",", ndmin=2)
        rows.append(elevations_from_rings(scan[:, :3], scan[:, 4].astype(np.int64), 32))
    return np.array(rows)


def shipped_table(per_frame: np.ndarray) -> np.ndarray:
    """Per-channel median over frames, rounded to 0.001 degree: the YAML values."""
    return np.round(np.median(per_frame, axis=0), 3)


def report(name: str, method: str, per_frame: np.ndarray) -> None:
    table = shipped_table(per_frame)
    spread = per_frame.max(axis=0) - per_frame.min(axis=0)
    steps = np.diff(table)
    print(f"== {name}: {method}")
    print(
        f"   {per_frame.shape[1]} channels, {table[0]:.3f} .. {table[-1]:.3f} deg; "
        f"spacing {steps.min():.3f} .. {steps.max():.3f}; "
        f"max frame-to-frame spread {spread.max():.3f} deg over {per_frame.shape[0]} frame(s)"
    )
    print(f"   vertical_fov_deg: {list(vertical_fov_deg(table))}")
    print(f"   elevation_deg: [{', '.join(f'{v:.3f}' for v in table)}]")


def main(argv: list[str]) -> int:
    data = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parents[2] / "shared/data"
    if not data.is_dir():
        print(f"data directory {data} not found; pass it as the first argument.")
        return 2
    kitti = measure_kitti(data)
    report("hdl64e (SemanticKITTI 00/000000-000002)", "scan order, median > 5 m", kitti)
    scan = np.fromfile(kitti_files(data)[0], dtype=np.float32).reshape(-1, 4)
    ring = rings_from_scan_order(scan[:, :3], 64)
    upper = ring >= 32
    print(
        f"   KITTI ring sizes {np.bincount(ring).min()}..{np.bincount(ring).max()}; "
        f"upper block spacing {np.diff(shipped_table(kitti)[32:]).mean():.3f}, "
        f"lower block {np.diff(shipped_table(kitti)[:32]).mean():.3f} deg; "
        f"{upper.sum()} points in the upper block"
    )
    report("hdl32e (nuScenes keyframe)", "ring column, median > 5 m", measure_nuscenes(data))
    report(
        "hdl32e cross-check (RADIATE 000018-20)", "ring column, median > 5 m", measure_radiate(data)
    )
    report("wads64 (WADS 36/042223-042225)", "elevation histogram peaks > 5 m", measure_wads(data))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
