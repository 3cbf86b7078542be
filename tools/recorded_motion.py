"""The motion each real frame's poses record, as `lads build --variant motion-recorded` reads it
(the readers' `pose_track`, `lads.physics.ego_motion.from_poses`): speed and turn rate per
frame, and their ranges (docs/augment.md §3).

    python tools/recorded_motion.py [DATA]

DATA is ../shared/data by default. SemanticKITTI sequence 00 uses KITTI's ground-truth poses
(kitti_odometry/poses/00.txt) as a stand-in for SemanticKITTI's poses.txt, linked with the
scans, calib.txt and times.txt into a temporary tree; the nuScenes KITTI-style export
(nuscenes-kittifmt) carries its own poses.txt.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from lads.physics.ego_motion import from_poses
from lads.readers.nuscenes_kitti import NuScenesKittiReader
from lads.readers.semantickitti import SemanticKittiReader


def _kitti_tree(data: Path, root: Path) -> Path:
    """A SemanticKITTI tree of every labelled real seq-00 scan with the stand-in poses."""
    seq = root / "sequences" / "00"
    (seq / "velodyne").mkdir(parents=True)
    for scan in sorted(data.glob("semantickitti*/sequences/00/velodyne/*.bin")):
        if scan.stat().st_size > 100_000 and not (seq / "velodyne" / scan.name).exists():
            os.symlink(scan.resolve(), seq / "velodyne" / scan.name)
    for name in ("calib.txt", "times.txt"):
        os.symlink((data / "semantickitti/sequences/00" / name).resolve(), seq / name)
    os.symlink((data / "kitti_odometry/poses/00.txt").resolve(), seq / "poses.txt")
    return root


def _report(name: str, reader: SemanticKittiReader | NuScenesKittiReader) -> None:
    speeds, yaws = [], []
    for item in reader.items():
        track = reader.pose_track(item)
        motion = from_poses(track.times_s, track.poses, track.centre, track.where)
        speeds.append(motion.speed_m_s)
        yaws.append(motion.yaw_rate_deg_s)
        print(
            f"{name} {item.relpath}: {motion.speed_m_s:.2f} m/s, {motion.yaw_rate_deg_s:.2f} deg/s"
        )
    print(
        f"{name}: {len(speeds)} frames, speed {min(speeds):.1f}-{max(speeds):.1f} m/s, "
        f"turn rate {min(yaws):.1f} to {max(yaws):.1f} deg/s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", type=Path, default=Path("../shared/data"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        _report("semantickitti seq 00", SemanticKittiReader(_kitti_tree(args.data, Path(tmp))))
    _report("nuscenes scene-0002", NuScenesKittiReader(args.data / "nuscenes-kittifmt"))


if __name__ == "__main__":
    main()
