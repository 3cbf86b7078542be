"""Ground incidence on thinned scans: range-image normals vs local ground planes.

    .venv/bin/python -m benchmarks.ground_incidence  -> benchmarks/results/ground_incidence.json

For every labelled SemanticKITTI frame of ../shared/data, the incidence cosine of the full
cloud's range-image normals is the reference. The frame is thinned to 40,000 random points,
as the concealed-effect benchmark's CI subset thins it, and two estimates are compared with
the reference on the ground-class points, per range band: the image normals of the thinned
cloud (`lads.physics.modalities.incidence`) and the local ground planes of
`lads.diagnose.data.ground_normals`. The numbers are the median |angle error| in degrees and the
median |ln cos error| (cos floored at 0.05, as the diagnosis' design floors it).
"""

from __future__ import annotations

import numpy as np

from benchmarks.common import SHARED_DATA, machine_info, write_result
from lads.diagnose.data.beams import GROUND_CLASSES
from lads.diagnose.data.ground_normals import local_ground_cos
from lads.physics.modalities import incidence
from lads.sensors.profile import load_profile

ROOT = SHARED_DATA / "semantickitti"
THIN_POINTS = 40000
BANDS_M = ((0.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, 80.0))


def _angle_deg(cos: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def _ln(cos: np.ndarray) -> np.ndarray:
    return np.log(np.clip(cos, 0.05, 1.0))


def _median_abs(diff: np.ndarray) -> float | None:
    return float(np.median(np.abs(diff))) if diff.size else None


def main() -> None:
    profile = load_profile("hdl64e")
    rows = []
    for scan in sorted(ROOT.rglob("velodyne/*.bin")):
        label_path = scan.parent.parent / "labels" / (scan.stem + ".label")
        if not label_path.is_file():
            continue
        raw = np.fromfile(scan, dtype="<f4").reshape(-1, 4)
        labels = np.fromfile(label_path, dtype="<u4") & 0xFFFF
        xyz = raw[:, :3].astype(np.float64)
        r = np.linalg.norm(xyz, axis=1)
        keep = r > 1.0
        xyz, labels, r = xyz[keep], labels[keep], r[keep]
        reference = incidence(xyz, profile).cos
        rng = np.random.default_rng(0)
        sub = np.sort(rng.choice(len(xyz), min(THIN_POINTS, len(xyz)), replace=False))
        ground = np.isin(labels[sub], GROUND_CLASSES["semantickitti"])
        image = incidence(xyz[sub], profile).cos
        plane, ok = local_ground_cos(xyz[sub], ground)
        ref = reference[sub]
        for lo, hi in BANDS_M:
            m = ground & (r[sub] >= lo) & (r[sub] < hi)
            mp = m & ok
            rows.append(
                {
                    "frame": scan.relative_to(ROOT).as_posix(),
                    "band_m": [lo, hi],
                    "ground_points": int(m.sum()),
                    "plane_share": float(mp.sum() / max(m.sum(), 1)),
                    "image_angle_err_deg": _median_abs(_angle_deg(image[m]) - _angle_deg(ref[m])),
                    "plane_angle_err_deg": _median_abs(_angle_deg(plane[mp]) - _angle_deg(ref[mp])),
                    "image_ln_cos_err": _median_abs(_ln(image[m]) - _ln(ref[m])),
                    "plane_ln_cos_err": _median_abs(_ln(plane[mp]) - _ln(ref[mp])),
                }
            )
    path = write_result(
        "ground_incidence.json",
        {
            "benchmark": "ground incidence on thinned scans: image normals vs local ground planes",
            "command": ".venv/bin/python -m benchmarks.ground_incidence",
            "thin_points": THIN_POINTS,
            "rows": rows,
            "machine": machine_info(),
        },
    )
    for row in rows:
        print(
            row["frame"],
            row["band_m"],
            row["ground_points"],
            row["image_angle_err_deg"],
            row["plane_angle_err_deg"],
        )  # noqa: T201
    print(f"wrote {path}")  # noqa: T201


if __name__ == "__main__":
    main()
