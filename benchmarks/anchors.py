"""Physical anchors and per-point modalities, as numbers (the tests only assert bounds).

- rain extinction alpha(R) from Marshall-Palmer + water Mie at 905 nm, against the
  Ulbrich-Atlas relation 1.45 R^0.64 dB/km, and two-way transmission over 100 m;
- Mie extinction efficiency of large water drops (tends to 2);
- incidence cosines of every point of real SemanticKITTI 00/000000 and where they came from.

Run: .venv/bin/python -m benchmarks.anchors   (writes benchmarks/results/anchors.json)
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import KITTI_SCANS, kitti_frames, machine_info, write_result
from lads.physics.mie import extinction_efficiency, extinction_per_m
from lads.physics.modalities import IncidenceSource, compute_modalities
from lads.physics.psd import marshall_palmer
from lads.sensors.profile import load_profile

RAIN_RATES_MM_H = (1.0, 5.0, 10.0, 25.0, 50.0, 100.0)
DB_PER_KM = math.log(10) / 10 / 1000  # 1 dB/km in 1/m


def rain_rows() -> list[dict[str, float]]:
    rows = []
    for rate in RAIN_RATES_MM_H:
        alpha = extinction_per_m(marshall_palmer(rate), "water", 905.0)
        ulbrich_atlas = 1.45 * rate**0.64 * DB_PER_KM
        rows.append(
            {
                "rate_mm_h": rate,
                "alpha_per_m": float(f"{alpha:.4g}"),
                "ulbrich_atlas_per_m": float(f"{ulbrich_atlas:.4g}"),
                "ratio_to_ulbrich_atlas": round(alpha / ulbrich_atlas, 4),
                "two_way_transmission_100_m": round(math.exp(-2 * alpha * 100.0), 4),
            }
        )
    return rows


def modalities_row() -> dict[str, Any]:
    points = kitti_frames()[0]
    labels = np.fromfile(
        KITTI_SCANS[0].parent.parent / "labels" / KITTI_SCANS[0].with_suffix(".label").name,
        dtype=np.uint32,
    )
    profile = load_profile("hdl64e")
    compute_modalities(points[:, :3], labels, "semantickitti", profile)  # warm-up
    start = time.perf_counter()
    mods = compute_modalities(points[:, :3], labels, "semantickitti", profile)
    elapsed_ms = 1e3 * (time.perf_counter() - start)
    return {
        "frame": "semantickitti 00/000000",
        "points": int(points.shape[0]),
        "cos_incidence_mean": round(float(mods.cos_incidence.mean()), 4),
        "cos_incidence_median": round(float(np.median(mods.cos_incidence)), 4),
        "source_share": {
            s.name.lower(): round(float(np.mean(mods.incidence_source == s)), 4)
            for s in IncidenceSource
        },
        "reflectance_mean": round(float(mods.reflectance.mean()), 4),
        "runtime_ms": round(elapsed_ms, 1),
    }


def main(out_dir: Path | None = None) -> dict[str, Any]:
    sizes = np.array([100.0, 1000.0, 3000.0, 10000.0])
    payload = {
        "what": __doc__.strip().splitlines()[0],
        "rain": rain_rows(),
        "water_extinction_efficiency": {
            f"x={x:g}": round(float(q), 4)
            for x, q in zip(
                sizes, extinction_efficiency("water", sizes * 905e-6 / math.pi, 905.0), strict=True
            )
        },
        "modalities": modalities_row(),
        "machine": machine_info(),
    }
    write_result("anchors.json", payload, out_dir)
    return payload


if __name__ == "__main__":
    main()
