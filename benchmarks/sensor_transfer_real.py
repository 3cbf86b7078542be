"""Sensor transfer on real scans (docs/transfer.md §5): SemanticKITTI (HDL-64E) frames with
KITTI ground-truth poses to the HDL-32E, and the labelled nuScenes scene-0002 keyframes
(HDL-32E, KITTI-style export with poses) to the HDL-64E. No real scene was recorded by both
sensors, so the transfers are compared with real scans of the target sensor from other places,
ring by ring: the share of a ring's beams that return, and the median range of its returns.

    python -m benchmarks.sensor_transfer_real   -> results/sensor_transfer_real.{json,md}

What this cannot show: beam-by-beam agreement (the proof of that is on ground truth,
benchmarks/sensor_transfer.py), and anything about rings outside the source's field of view.
KITTI's poses.txt here is the KITTI odometry ground truth (kitti_odometry/poses/00.txt), not
SemanticKITTI's own SuMa poses, which the reference data lack.
"""

from __future__ import annotations

import argparse
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import RESULTS, SHARED_DATA, machine_info, write_result
from lads.physics.projection import MIN_RANGE_M
from lads.readers import get_reader
from lads.sensors.profile import SensorProfile, load_profile
from lads.transfer.fov import covered_rings
from lads.transfer.scan import WindowScan, transfer_surfels, window_surfels
from lads.transfer.window import DEFAULT_NEIGHBOURS, window_of
from tests.trees import _link

# Beyond this range a return is not the recording vehicle's body (nuScenes: every return
# within 1.1 m is labelled vehicle.ego; KITTI's roof-mounted sensor sees no body).
BODY_M = 2.5
KITTI_FRAMES = ("000000", "000001", "000002", "000052", "000088", "000850", "004501")


def kitti_tree(root: Path) -> Path:
    """The real SemanticKITTI frames of sequence 00 with calib.txt and the KITTI ground-truth
    poses as poses.txt (line i for scan i)."""
    seq = root / "sequences" / "00"
    for name in KITTI_FRAMES:
        for folder in ("semantickitti", "semantickitti-more"):
            src = SHARED_DATA / folder / "sequences" / "00"
            if (src / "velodyne" / f"{name}.bin").is_file():
                _link(src / "velodyne" / f"{name}.bin", seq / "velodyne" / f"{name}.bin")
                _link(src / "labels" / f"{name}.label", seq / "labels" / f"{name}.label")
    _link(SHARED_DATA / "semantickitti" / "sequences" / "00" / "calib.txt", seq / "calib.txt")
    _link(SHARED_DATA / "kitti_odometry" / "poses" / "00.txt", seq / "poses.txt")
    return root


def transfer_tree(reader: Any, source: SensorProfile, target: SensorProfile) -> list[Any]:
    """Every scan of the tree transferred with its window, as a build chooses it
    (`lads.transfer.window`)."""
    items = reader.items()
    poses = reader.sensor_poses(items)
    frames = {it.relpath: reader.read(it) for it in items}
    surfels = {}
    for it in items:
        f = frames[it.relpath]
        ring = f.points[:, f.columns.index("ring")] if "ring" in f.columns else None
        scan = WindowScan(f.xyz, f.intensity, f.labels, ring, poses[it.relpath])
        surfels[it.relpath] = window_surfels(scan, source, reader.label_set)
    out = []
    for it in items:
        window, centre = window_of(items, it, DEFAULT_NEIGHBOURS, reader.scan_position)
        near = [o.relpath for o in window]
        moved = transfer_surfels(
            [surfels[r] for r in near],
            [poses[r] for r in near],
            centre,
            source,
            target,
            np.random.default_rng(0),
            label_set=reader.label_set,
        )
        out.append((len(near), moved))
    return out


def ring_stats(xyz: Any, ring: Any, channels: int, beams_per_ring: float) -> dict[str, Any]:
    """Per ring: share of beams returned (returns beyond BODY_M / beams per ring) and the
    median range of those returns (m, None when empty)."""
    pts = np.asarray(xyz, np.float64)
    r = np.linalg.norm(pts, axis=1)
    ok = r > max(BODY_M, MIN_RANGE_M)
    ring = np.asarray(ring, np.int64)
    share = np.bincount(ring[ok], minlength=channels) / beams_per_ring
    med = [
        float(np.median(r[ok & (ring == k)])) if (ok & (ring == k)).any() else None
        for k in range(channels)
    ]
    return {"share": share.tolist(), "median_range_m": med}


def _mean_stats(stats: list[dict[str, Any]]) -> dict[str, Any]:
    share = np.mean([s["share"] for s in stats], axis=0)
    meds = np.array([[np.nan if v is None else v for v in s["median_range_m"]] for s in stats])
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a ring no scan returned on
        med = np.nanmedian(meds, axis=0)
    return {
        "share": share.tolist(),
        "median_range_m": [None if np.isnan(v) else float(v) for v in med],
    }


def real_hdl32e() -> dict[str, Any]:
    """Ring statistics of the 40 real scene-0001 keyframes (their own ring column)."""
    reader = get_reader("nuscenes-scans", SHARED_DATA / "nuscenes-scene0001")
    stats = []
    for it in reader.items():
        f = reader.read(it)
        stats.append(ring_stats(f.xyz, f.points[:, 4], 32, BEAMS_PER_RING["hdl32e"]))
    return _mean_stats(stats)


def real_hdl64e(reader: Any) -> dict[str, Any]:
    """Ring statistics of the real KITTI frames (channel by nearest elevation: no ring column)."""
    profile = load_profile("hdl64e")
    stats = []
    for it in reader.items():
        f = reader.read(it)
        stats.append(
            ring_stats(
                f.xyz, profile.channel_of(f.xyz.astype(np.float64)), 64, BEAMS_PER_RING["hdl64e"]
            )
        )
    return _mean_stats(stats)


# Firings per ring and revolution of the real sensors: nuScenes' HDL-32E at 20 Hz fires about
# 1,085 times per ring (docs/formats.md §2.2), KITTI's HDL-64E about 2,000 at 10 Hz (its
# rings hold up to ~2,080 returns). Transfers fire the profile's range_image_width.
BEAMS_PER_RING = {"hdl32e": 1085.0, "hdl64e": 2000.0}
COLUMNS = ("share_transfer", "share_real", "median_range_transfer_m", "median_range_real_m")


def direction(
    name: str,
    transfers: list[Any],
    target: SensorProfile,
    source: SensorProfile,
    real: dict[str, Any],
) -> dict[str, Any]:
    stats = [
        ring_stats(m.xyz, m.ring, target.channels, float(target.range_image_width))
        for _, m in transfers
    ]
    mine = _mean_stats(stats)
    covered = covered_rings(source.elevation_deg, target.elevation_deg)
    rows = []
    for k in range(target.channels):
        rows.append(
            {
                "ring": k,
                "elevation_deg": target.elevation_deg[k],
                "covered": bool(covered[k]),
                "share_transfer": mine["share"][k],
                "share_real": real["share"][k],
                "median_range_transfer_m": mine["median_range_m"][k],
                "median_range_real_m": real["median_range_m"][k],
            }
        )
    cov = [r for r in rows if r["covered"]]
    share_gap = [abs(r["share_transfer"] - r["share_real"]) for r in cov]
    return {
        "direction": name,
        "scans": len(transfers),
        "window_sizes": [n for n, _ in transfers],
        "rings": rows,
        "mean_abs_share_gap_covered": float(np.mean(share_gap)),
        "share_transfer_covered": float(np.mean([r["share_transfer"] for r in cov])),
        "share_real_covered": float(np.mean([r["share_real"] for r in cov])),
    }


def markdown(result: dict[str, Any]) -> str:
    lines = ["# Sensor transfer on real scans (ring statistics against real target scans)", ""]
    for d in result["directions"]:
        lines += [
            f"## {d['direction']} ({d['scans']} scans)",
            "",
            f"Returned share of beams on covered rings: transfer "
            f"{d['share_transfer_covered']:.3f}, real target scans "
            f"{d['share_real_covered']:.3f}; mean |gap| per ring "
            f"{d['mean_abs_share_gap_covered']:.3f}.",
            "",
            "| ring | elevation | covered | share transfer | share real | "
            "median range transfer (m) | median range real (m) |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in d["rings"]:

            def f(v: Any) -> str:
                return "—" if v is None else f"{v:.2f}"

            cells = [f(r[c]) for c in COLUMNS]
            lines.append(
                f"| {r['ring']} | {r['elevation_deg']:.2f} | {r['covered']} | "
                + " | ".join(cells)
                + " |"
            )
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--results", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    hdl64, hdl32 = load_profile("hdl64e"), load_profile("hdl32e")
    with tempfile.TemporaryDirectory() as tmp:
        kitti = get_reader("semantickitti", kitti_tree(Path(tmp) / "kitti"))
        nusc = get_reader("nuscenes-kitti", SHARED_DATA / "nuscenes-kittifmt")
        to32 = transfer_tree(kitti, hdl64, hdl32)
        to64 = transfer_tree(nusc, hdl32, hdl64)
        result = {
            "machine": machine_info(),
            "directions": [
                direction("SemanticKITTI HDL-64E -> HDL-32E", to32, hdl32, hdl64, real_hdl32e()),
                direction("nuScenes HDL-32E -> HDL-64E", to64, hdl64, hdl32, real_hdl64e(kitti)),
            ],
        }
    write_result("sensor_transfer_real.json", result, args.results)
    (args.results / "sensor_transfer_real.md").write_text(markdown(result))
    print(markdown(result))


if __name__ == "__main__":
    main()
