"""Where crosstalk's false returns land on a real scan: the share within 45 deg of the
interferer's azimuth against the share of all beams there, and the range of the targets they
replace (docs/augment.md §3, crosstalk).

    python tools/crosstalk_direction.py [SCAN.bin] [--share 0.01]

SCAN.bin is a SemanticKITTI scan (float32 x, y, z, remission); default: frame 000000 of
sequence 00 in ../shared/data.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lads.physics.echo_faults import crosstalk
from lads.physics.result import Outcome

DEFAULT_SCAN = Path("../shared/data/semantickitti/sequences/00/velodyne/000000.bin")


def _offset_deg(azimuth_deg: np.ndarray, towards_deg: float) -> np.ndarray:
    return np.abs((azimuth_deg - towards_deg + 180.0) % 360.0 - 180.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scan", nargs="?", type=Path, default=DEFAULT_SCAN)
    parser.add_argument("--share", type=float, default=0.01, help="interfered share (heavy)")
    args = parser.parse_args()
    points = np.fromfile(args.scan, "<f4").reshape(-1, 4)
    azimuth = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
    range_m = np.linalg.norm(points[:, :3], axis=1)
    for towards in (0.0, 90.0, 180.0):
        res = crosstalk(
            points[:, :3],
            points[:, 3],
            sensor="hdl64e",
            rng=np.random.default_rng(0),
            interfered_share=args.share,
            interferer_azimuth_deg=towards,
        )
        rows = res.source_index[res.outcome == Outcome.PARTICLE]
        near = _offset_deg(azimuth[rows], towards) < 45.0
        beams = _offset_deg(azimuth, towards) < 45.0
        print(
            f"interferer at {towards:5.1f} deg: {rows.size} false returns, "
            f"{near.mean():.2f} within 45 deg (beams there {beams.mean():.2f}); "
            f"median range of replaced targets {np.median(range_m[rows]):.1f} m "
            f"(all returns {np.median(range_m):.1f} m)"
        )


if __name__ == "__main__":
    main()
