"""Real WADS frames for the snow calibration: reading them, their falling-snow statistics and
the clear scene left when the falling snow is removed (docs/physics.md §5.3; the fit is in
`lads.calibration.wads`).

WADS is a dual-return recording: ~42 % of rows are exact duplicates (the strongest and the
last return of one firing), which `duplicate_mask` finds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import InputDataError
from lads.frame import Frame
from lads.physics.materials import MAX_CLASS_ID, has_instance_bits
from lads.readers import read_scan, read_scans
from lads.readers.wads import WadsReader

FALLING_SNOW = 110
ACCUMULATED_SNOW = 111
PERCENTILES = (5, 50, 95)


@dataclass(frozen=True, slots=True)
class WadsFrame:
    """One WADS scan as stored: points (N, 4) float32 x, y, z, intensity 0-255; labels (N,)."""

    name: str
    points: npt.NDArray[np.float32]
    labels: npt.NDArray[np.uint32]


def load_frame(bin_path: str | Path) -> WadsFrame:
    """One WADS scan `sequences/NN/velodyne/X.bin` and its labels, read by the WADS reader;
    labels reduced to the semantic class (instance bits removed, materials.yaml).

    Raises:
        InputDataError: the file is not a scan of a WADS tree, or has no label file.
        CorruptItemError: the reader refuses the scan or its labels (the message names them).
    """
    path = Path(bin_path)
    return _wads_frame(path, read_scan("wads", path.parents[3], path))


def load_sequence(sequence_dir: str | Path, names: Sequence[str]) -> list[WadsFrame]:
    """Frames `names` (e.g. "042223") of a WADS sequence folder (velodyne/, labels/); the
    WADS reader names their files (`new_item`)."""
    folder = Path(sequence_dir)
    root = folder.parents[1]
    reader = WadsReader(root)
    paths = [root / reader.new_item(folder.name, int(n)).relpath for n in names]
    if not paths:
        return []
    frames = read_scans("wads", root, paths)
    return [_wads_frame(p, f) for p, f in zip(paths, frames, strict=True)]


def _wads_frame(path: Path, frame: Frame) -> WadsFrame:
    if frame.labels is None:
        raise InputDataError(
            f"{path}: no label file beside it (labels/{path.stem}.label); the snow fit needs "
            "the falling-snow labels."
        )
    raw = frame.labels.astype(np.uint32, copy=False)
    labels = raw & np.uint32(MAX_CLASS_ID) if has_instance_bits("wads") else raw
    return WadsFrame(path.stem, frame.points, labels)


def duplicate_mask(points: npt.NDArray[np.float32]) -> npt.NDArray[np.bool_]:
    """(N,) True for rows that have an exact duplicate (dual return: strongest = last)."""
    _, inverse, counts = np.unique(points, axis=0, return_inverse=True, return_counts=True)
    return counts[inverse.ravel()] > 1


@dataclass(frozen=True, slots=True)
class SnowScene:
    """A WADS frame split into the clear scene and the comparable real snow.

    Attributes:
        name: frame name.
        clear_xyz: (M, 3) float32, unique non-snow points (one beam each), m.
        clear_intensity: (M,) float32, their intensities (0-255).
        snow_range_m: (K,) float64 ranges of the real flakes in front of a recorded target
            (unique, non-duplicated label-110 points): what the simulation can reproduce.
        snow_intensity: (K,) float32 their intensities.
        real: measured statistics of the frame (`real_snow_stats`).
    """

    name: str
    clear_xyz: npt.NDArray[np.float32]
    clear_intensity: npt.NDArray[np.float32]
    snow_range_m: npt.NDArray[np.float64]
    snow_intensity: npt.NDArray[np.float32]
    real: dict[str, Any] = field(default_factory=dict)

    @property
    def target_fraction(self) -> float:
        """Real flakes in front of targets / (clear points + those flakes)."""
        k = self.snow_range_m.size
        return k / (len(self.clear_xyz) + k)


def percentiles(x: npt.NDArray[Any]) -> list[float]:
    """The PERCENTILES of `x` rounded to 3 decimals (NaN each when empty)."""
    if x.size == 0:
        return [math.nan] * len(PERCENTILES)
    return [round(float(v), 3) for v in np.percentile(x, PERCENTILES)]


def real_snow_stats(frame: WadsFrame) -> dict[str, Any]:
    """Label-110 statistics of one frame: shares, ranges, intensities, dual-return split."""
    pts, lab = frame.points, frame.labels
    rng_m = np.linalg.norm(pts[:, :3].astype(np.float64), axis=1)
    snow_rows = lab == FALLING_SNOW
    dup = duplicate_mask(pts)
    first = np.zeros(len(pts), dtype=bool)
    first[np.unique(pts, axis=0, return_index=True)[1]] = True
    unique_snow = snow_rows & first
    targeted = snow_rows & ~dup
    n_unique = int(first.sum())
    inten = pts[snow_rows, 3]
    return {
        "rows": len(pts),
        "unique_rows": n_unique,
        "duplicate_row_share": round(1 - n_unique / len(pts), 4),
        "snow_rows": int(snow_rows.sum()),
        "snow_row_fraction": round(float(snow_rows.mean()), 5),
        "snow_unique_fraction": round(float(unique_snow.sum() / n_unique), 5),
        "snow_in_front_of_target": int(targeted.sum()),
        "snow_without_target_unique": int((unique_snow & dup).sum()),
        "snow_target_fraction": round(
            float(targeted.sum() / ((first & ~snow_rows).sum() + targeted.sum())), 5
        ),
        "snow_range_pct_rows": percentiles(rng_m[snow_rows]),
        "snow_range_pct_in_front_of_target": percentiles(rng_m[targeted]),
        "snow_intensity_zero_share": round(float((inten == 0).mean()), 4),
        "snow_intensity_p99": float(np.percentile(inten, 99)),
        "other_intensity_zero_share": round(float((pts[~snow_rows, 3] == 0).mean()), 4),
        "duplicated_share_of_snow_rows": round(float(dup[snow_rows].mean()), 4),
        "duplicated_share_of_other_rows": round(float(dup[~snow_rows].mean()), 4),
    }


def scene_from_frame(frame: WadsFrame) -> SnowScene:
    """Clear scene (unique non-110 rows) and the comparable real flakes of one frame."""
    pts, lab = frame.points, frame.labels
    clear = np.unique(pts[lab != FALLING_SNOW], axis=0)
    targeted = (lab == FALLING_SNOW) & ~duplicate_mask(pts)
    snow_pts = pts[targeted]
    return SnowScene(
        name=frame.name,
        clear_xyz=np.ascontiguousarray(clear[:, :3]),
        clear_intensity=np.ascontiguousarray(clear[:, 3]),
        snow_range_m=np.linalg.norm(snow_pts[:, :3].astype(np.float64), axis=1),
        snow_intensity=snow_pts[:, 3].copy(),
        real=real_snow_stats(frame),
    )
