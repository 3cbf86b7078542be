"""Fog model vs real fog (RADIATE fog_6_0, HDL-32E): what the three sample frames can show.

    .venv/bin/python -m benchmarks.fog_radiate

Writes benchmarks/results/fog_radiate.json. No clear-weather twin and no visibility record
exist for these frames, so only a bound is computed: the smallest visibility (MOR) at which
our fog model, run on the frame's clean half (azimuth 0..180 deg) with the frame's own
detection threshold, produces no more near (< 3 m) fog returns than the real frame shows,
for several overlap ranges R2 and both backscatter models (lads.calibration.radiate).
"""

from __future__ import annotations

import time
from typing import Any

from benchmarks.common import SHARED_DATA, machine_info, write_result
from lads.calibration import radiate as R
from lads.errors import InputDataError
from lads.physics.fog import FogParams
from lads.physics.weather import FAINT_FULL_M, FAINT_ONSET_M, FOG_DEFAULTS

FOLDER = SHARED_DATA / "radiate" / "tiny_foggy" / "velo_lidar"
FRAMES = ("000018", "000019", "000020")
OVERLAP_FULL_M = (1.0, 2.0, 3.0, 5.0, 8.0)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    if not FOLDER.is_dir():
        raise InputDataError(f"RADIATE sample missing at {FOLDER} (see ../shared/data).")
    start = time.perf_counter()
    frames = [R.load_frame(FOLDER / f"{n}.csv") for n in FRAMES]
    bounds = []
    for r2 in OVERLAP_FULL_M:
        for model in ("mie", "hahner"):
            params = FogParams(overlap_start_m=min(0.9, r2), overlap_full_m=r2,
                               backscatter_model=model)  # fmt: skip
            per_frame = [R.visibility_bound(f, params=params) for f in frames]
            bounds.append({
                "overlap_full_m": r2, "backscatter_model": model,
                "min_visibility_consistent_m": [b["min_visibility_consistent_m"]
                                                for b in per_frame],
                "curve_frame_000018": per_frame[0]["curve"],
            })  # fmt: skip
    shipped = [R.visibility_bound(f, params=FOG_DEFAULTS) for f in frames]
    bounds.append({
        "overlap_full_m": FOG_DEFAULTS.overlap_full_m, "backscatter_model": "mie",
        "shipped_defaults": True,
        "min_visibility_consistent_m": [b["min_visibility_consistent_m"] for b in shipped],
        "curve_frame_000018": shipped[0]["curve"],
    })  # fmt: skip
    payload = {
        "description": __doc__.strip().splitlines()[0],
        "data": {
            "folder": str(FOLDER.relative_to(SHARED_DATA.parent)),
            "frames": FRAMES,
            "meta": "fog_6_0 (RADIATE test set); no visibility recorded",
        },  # fmt: skip
        "real": {f.name: R.frame_stats(f) for f in frames},
        "detection_threshold_per_frame": {f.name: R.frame_threshold(f) for f in frames},
        "visibility_bounds": bounds,
        "findings": [
            "~28 % of returns lie within 3 m, but 95 % of them come from azimuths -180..0 deg "
            "with a spike at 0.50-0.55 m: the vehicle's own structure, not fog. The clean "
            "half holds near returns on < 1 % of its beams (mostly at 0.5 m as well).",
            "With the HDL-32E profile's overlap (full at 1 m) our model puts a fog echo at "
            "~1.6-1.8 m on nearly every beam without a strong target for every visibility up "
            "to 5 km: contradicted by the data. Only a slow overlap (R2 >= 2-8 m, depending "
            "on the backscatter model) or a sensor that suppresses faint near echoes makes "
            "the model consistent, and then only for MOR >= 1-5 km, i.e. a bound, not a "
            "visibility estimate. The same near-range suppression shows in WADS snow (fitted "
            "R1 ~3.5 m, R2 ~5.9 m).",
            f"The shipped FOG_DEFAULTS take the WADS faint-return onset ({FAINT_ONSET_M} -> "
            f"{FAINT_FULL_M} m) and so put fog echoes beyond this check's 3 m window: they pass "
            "it trivially, and whether this HDL-32E shows fog echoes there cannot be told "
            "apart from scene returns in these frames.",
            "The visibility bounds use each frame's own weakest return as the threshold (an "
            "upper bound on the sensor's). With the default rule (the sensor's detection "
            "limit, docs/physics.md 9.7) dense fog still returns a fog echo on every beam "
            "whose target is lost, while real foggy frames return on only ~29 % of beams: "
            "fog beam loss is not modelled yet.",
        ],
        "cannot_show": [
            "extinction: no clear twin and no visibility record, so lost points and "
            "intensity damping cannot be attributed to fog rather than to scene content "
            "(open sky, dark materials); the 29 % return share and 58 m maximum range are "
            "consistent with fog but also with an open scene",
            "the fog visibility itself (only a model-dependent lower bound)",
            "the HDL-32E's true detection threshold (the weakest return is an upper bound) "
            "and overlap function, which the bound depends on",
            "intensity response: the sensor reports calibrated reflectivity with its own "
            "gain logic (docs/physics.md §5.3), not received power",
            "generality: 3 consecutive frames (0.2 s) of one sequence",
        ],
        "seconds": round(time.perf_counter() - start, 1),
        "machine": machine_info(),
    }
    write_result("fog_radiate.json", payload)
    return payload


if __name__ == "__main__":
    out = main()
    for b in out["visibility_bounds"]:
        print(b["overlap_full_m"], b["backscatter_model"], b["min_visibility_consistent_m"])
