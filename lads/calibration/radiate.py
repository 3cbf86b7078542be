"""What real fog (RADIATE, HDL-32E) can and cannot say about the fog model.

RADIATE's `fog_6_0` sample holds foggy HDL-32E frames, but no clear-weather twin of the same
scene and no visibility measurement. So the fog model cannot be checked on what fog does to
a given scene (lost points, attenuated intensities); only on what a foggy frame looks like.

Measured on the three sample frames (see `frame_stats`): ~20k returns of the HDL-32E's ~69k
beams per sweep; range 0.5-60 m; ~28 % of returns lie within 2 m, but they are not fog: they
come almost only from azimuths -180..0 deg (the vehicle's own structure behind / beside the
sensor, a spike at 0.50-0.55 m), while homogeneous fog would return equally in every
azimuth. The azimuths 0..180 deg hold almost no returns within 3 m.

Hence the one quantitative statement: in the clean half of the sweep the share of beams
with a near (< 3 m) return bounds the isotropic fog clutter from above. `visibility_bound`
finds the smallest visibility at which our fog model (strongest return, the frame's own
detection threshold) produces no more near fog returns than that: the fog in the frame must
be at least that thin, or the model overestimates fog backscatter. Beams that returned
nothing (sky, or lost in fog) are included as targets too far and too dark to be seen, so
the fog return is the only possible echo on them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.physics.beams import auto_threshold, prepare_beams
from lads.physics.fog import FogParams, simulate_fog
from lads.physics.result import Outcome
from lads.physics.weather import FOG_DEFAULTS
from lads.readers import read_scan
from lads.sensors.profile import SensorProfile, load_profile

SENSOR = "hdl32e"
NEAR_M = 3.0
CLEAN_AZIMUTH_DEG = (0.0, 180.0)
# HDL-32E: 32 lasers, ~2,170 firings per rotation at 10 Hz (0.166 deg azimuth steps).
FIRINGS_PER_SWEEP = 2170
NO_RETURN_RANGE_M = 150.0


@dataclass(frozen=True, slots=True)
class RadiateFrame:
    """One RADIATE lidar CSV: xyz (N, 3) m, intensity (N,) 0-255, ring (N,) 0-31."""

    name: str
    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    ring: npt.NDArray[np.int64]


def load_frame(csv_path: str | Path) -> RadiateFrame:
    """One RADIATE scan `<sequence>/velo_lidar/NNNNNN.csv`, read by the RADIATE reader.

    Raises:
        InputDataError: the file is not a scan of a RADIATE sequence folder.
        CorruptItemError: the reader refuses the file (the message names it).
    """
    path = Path(csv_path)
    frame = read_scan("radiate", path.parent.parent, path)
    points = frame.points
    return RadiateFrame(
        path.stem,
        np.ascontiguousarray(points[:, :3]),
        points[:, 3].copy(),
        points[:, 4].astype(np.int64),
    )


def in_clean_half(xyz: npt.NDArray[np.floating]) -> npt.NDArray[np.bool_]:
    """(N,) True for points (N, 3) m in the half of the sweep free of the vehicle's structure
    (azimuth in CLEAN_AZIMUTH_DEG)."""
    az = np.degrees(np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0]))
    return (az >= CLEAN_AZIMUTH_DEG[0]) & (az < CLEAN_AZIMUTH_DEG[1])


def frame_stats(frame: RadiateFrame) -> dict[str, Any]:
    """Point count, ranges, intensities, and near returns per azimuth half."""
    r = np.linalg.norm(frame.xyz.astype(np.float64), axis=1)
    clean = in_clean_half(frame.xyz)
    near = r < NEAR_M
    beams_half = FIRINGS_PER_SWEEP * 32 / 2
    return {
        "points": int(r.size),
        "beams_per_sweep": FIRINGS_PER_SWEEP * 32,
        "return_share": round(r.size / (FIRINGS_PER_SWEEP * 32), 4),
        "range_pct_5_50_95": [round(float(v), 2) for v in np.percentile(r, (5, 50, 95))],
        "max_range_m": round(float(r.max()), 2),
        "range_p99_m": round(float(np.percentile(r, 99)), 2),
        "intensity_max": float(frame.intensity.max()),
        "intensity_median_beyond_3m": float(np.median(frame.intensity[~near])),
        "near_returns_total": int(near.sum()),
        "near_returns_azimuth_0_180": int((near & clean).sum()),
        "near_returns_azimuth_-180_0": int((near & ~clean).sum()),
        "near_share_of_beams_clean_half": round(float((near & clean).sum() / beams_half), 6),
        "near_clean_range_pct_5_50_95": (
            [round(float(v), 2) for v in np.percentile(r[near & clean], (5, 50, 95))]
            if (near & clean).any()
            else None
        ),
    }


def clean_half_beams(
    frame: RadiateFrame,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Beams of the clean half as a frame to fog: xyz (M, 3) m, intensity (M,) 0-255.

    The returns beyond NEAR_M plus one dark, far stand-in (NO_RETURN_RANGE_M, intensity 0)
    per beam that returned nothing.
    """
    r = np.linalg.norm(frame.xyz.astype(np.float64), axis=1)
    keep = in_clean_half(frame.xyz) & (r >= NEAR_M)
    xyz, inten = frame.xyz[keep], frame.intensity[keep]
    profile = load_profile(SENSOR)
    n_missing = max(FIRINGS_PER_SWEEP * 16 - int(keep.sum()), 0)
    rng = np.random.default_rng(0)
    el = np.radians(np.asarray(profile.elevation_deg)[rng.integers(0, 32, n_missing)])
    az = np.radians(rng.uniform(*CLEAN_AZIMUTH_DEG, n_missing))
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    far = (NO_RETURN_RANGE_M * d).astype(np.float32)
    return np.vstack([xyz, far]), np.concatenate([inten, np.zeros(n_missing, np.float32)])


def near_fog_share(
    xyz: npt.NDArray[np.float32],
    intensity: npt.NDArray[np.float32],
    visibility_m: float,
    detection_threshold: float,
    *,
    params: FogParams | None = None,
    sensor: SensorProfile | str = SENSOR,
    seed: int = 0,
) -> tuple[float, npt.NDArray[np.float64]]:
    """Share of beams whose output is a fog return nearer than NEAR_M, and those ranges."""
    profile = load_profile(sensor) if isinstance(sensor, str) else sensor
    fog_params = params or FOG_DEFAULTS
    if hasattr(fog_params, "resolved_for"):  # overlap ranges taken from the profile
        fog_params = fog_params.resolved_for(profile)
    beams = prepare_beams(xyz, intensity, profile)
    res = simulate_fog(
        beams,
        profile,
        visibility_m=visibility_m,
        rng=np.random.default_rng(seed),
        params=replace(fog_params, detection_threshold=detection_threshold),
    )
    fog = res.outcome == Outcome.PARTICLE
    r = np.linalg.norm(res.xyz[fog].astype(np.float64), axis=1)
    return float((r < NEAR_M).sum() / len(xyz)), r


def frame_threshold(frame: RadiateFrame) -> float:
    """Weakest received return of the foggy frame: an upper bound on the sensor's P_min."""
    return auto_threshold(prepare_beams(frame.xyz, frame.intensity, load_profile(SENSOR)))


VISIBILITIES_M = (20, 50, 100, 200, 500, 1000, 2000, 5000)


def visibility_bound(
    frame: RadiateFrame,
    visibilities_m: Sequence[float] = VISIBILITIES_M,
    params: FogParams | None = None,
) -> dict[str, Any]:
    """Smallest visibility whose simulated near fog share does not exceed the observed one.

    Visibilities (MOR) in m; `params` None is FOG_DEFAULTS (the shipped faint-return onset).
    """
    observed = frame_stats(frame)["near_share_of_beams_clean_half"]
    xyz, inten = clean_half_beams(frame)
    p_min = frame_threshold(frame)
    curve: list[dict[str, Any]] = []
    for v in visibilities_m:
        share, r = near_fog_share(xyz, inten, v, p_min, params=params)
        curve.append(
            {
                "visibility_m": v,
                "near_fog_share": round(share, 6),
                "fog_range_pct_5_50_95": (
                    [round(float(x), 2) for x in np.percentile(r, (5, 50, 95))] if r.size else None
                ),
            }
        )
    ok = [c["visibility_m"] for c in curve if c["near_fog_share"] <= observed]
    return {
        "observed_near_share_clean_half": observed,
        "detection_threshold_used": p_min,
        "curve": curve,
        "min_visibility_consistent_m": min(ok) if ok else None,  # None: beyond the grid
    }
