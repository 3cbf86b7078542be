"""Weather realism report: what each weather and severity does to real scans, beside the
real adverse-weather recordings ../shared/data holds.

    .venv/bin/python -m benchmarks.realism  -> benchmarks/results/realism.json, realism.png

Simulated: rain, snow and fog at each severity preset (`lads.physics.severity`) on the
labelled real SemanticKITTI frames, physics only (`lads.physics.weather` with the shipped
defaults, strongest return, one generator per frame and setting), and rain and snow again
with LISA's published settings (fixed threshold; `--weather-settings lisa`). The heavy
presets run again with the frame-calibrated threshold and with other spreads of the
sensor's detection curve (docs/physics.md §9.7), and wet ground runs at each severity's water
film (docs/physics.md §8.2). Per setting:
- lost: share of the input points that no longer return, overall and per range bin of the
  source point;
- particle: drop, flake or fog returns as a share of the output points, overall and per
  range bin of the return;
- intensity: median output / input reflectivity of the attenuated points per material (the
  materials with at least MIN_CLASS_POINTS of them).

Real references (other sensors, places and weather strengths: shapes to set beside the
simulation, not targets it is scored on):
- WADS falling snow (label 110, wads64): share of the unique returns (dual-return duplicates
  removed), overall and per range bin;
- RADIATE fog (HDL-32E): returns beyond the vehicle's body per fired beam (2170 firings x 32
  lasers per sweep) in the half of the sweep free of the vehicle's structure, and their
  share per range bin (lads.calibration.radiate_share).
A KITTI frame holds only the beams that returned in clear air, so the simulated shares are
relative to those, and a real foggy frame's share is relative to every beam fired. Fog runs
again on real nuScenes frames (the HDL-32E, RADIATE's sensor), which store a point for
nearly every firing, so there the share of fired beams returning beyond the vehicle's body
is RADIATE's measure (benchmarks/fog_radiate.py fits a visibility to it).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from benchmarks.common import RESULTS, SHARED_DATA, machine_info, write_result
from lads.calibration import radiate, wads
from lads.calibration.radiate_share import BODY_M, radiate_profile
from lads.calibration.radiate_share import RANGE_BINS_M as SHARE_BINS_M
from lads.errors import InputDataError
from lads.physics import weather as wx
from lads.physics.fog import (
    backscatter_from_visibility,
    extinction_from_visibility,
    soft_return_peak,
)
from lads.physics.materials import material_index_for_labels, material_names, wet_surface_for_labels
from lads.physics.result import Outcome
from lads.physics.severity import PRESETS, SEVERITIES, preset
from lads.physics.wet_ground import WATER_REFRACTIVE_INDEX as WATER_N
from lads.physics.wet_ground import (
    WetGroundParams,
    internal_diffuse_reflectance,
    wet_ground,
    wet_ratio,
)
from lads.readers import get_reader
from lads.sensors.profile import load_profile

KITTI_ROOTS = ("semantickitti", "semantickitti-more", "semantickitti-seqx")
WADS_ROOTS = ("wads", "wads-more")
RANGE_BINS_M = (0.0, 5.0, 10.0, 20.0, 40.0, np.inf)  # KITTI holds a handful of points past 80 m
MIN_CLASS_POINTS = 1000
NUSCENES_FIRINGS = 32 * 1084  # HDL-32E lasers x firings per 20 Hz sweep (hdl32e.yaml)
NUSCENES_STRIDE = 4  # every 4th of the 40 frames: 0.2 s apart, enough for shares
NUSCENES_FOG_MOR_M = (20.0, 50.0, 150.0, 600.0)
SPREADS_LN = (0.25, 0.5, 1.0)  # around the spread measured on the HDL-32E (0.39)
SIMULATE = {"rain": wx.rain, "snow": wx.snow, "fog": wx.fog}
WEATHERS = tuple(SIMULATE)


def _bin_labels() -> list[str]:
    edges = zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:], strict=True)
    return [f"{a:g}-{b:g} m" if np.isfinite(b) else f">{a:g} m" for a, b in edges]


def _share_per_bin(
    range_m: npt.NDArray[np.float64], flag: npt.NDArray[np.bool_]
) -> list[float | None]:
    """Share of `flag` among the points of each range bin (None for an empty bin)."""
    out: list[float | None] = []
    for lo, hi in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:], strict=True):
        inside = (range_m >= lo) & (range_m < hi)
        out.append(round(float(flag[inside].mean()), 5) if inside.any() else None)
    return out


def _points_per_bin(frames: list[Any]) -> list[int]:
    r = np.concatenate([np.linalg.norm(p[:, :3].astype(np.float64), axis=1) for p, _ in frames])
    return [int(c) for c in np.histogram(r, bins=np.asarray(RANGE_BINS_M))[0]]


def _kitti_frames() -> list[tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]]:
    frames = []
    for root in KITTI_ROOTS:
        folder = SHARED_DATA / root
        if not folder.is_dir():
            raise InputDataError(f"real SemanticKITTI frames missing at {folder} (../shared/data).")
        reader = get_reader("semantickitti", folder)
        for item in reader.items():
            frame = reader.read(item)
            if frame.labels is not None:
                frames.append((frame.points[:, :4].copy(), frame.labels))
    return frames


def _simulate(
    weather: str,
    severity: str,
    frames: list[Any],
    settings: str = "lads",
    detection: str | None = None,
    spread_ln: float | None = None,
) -> dict[str, Any]:
    """Pooled statistics of one weather at one severity over the KITTI frames, with the
    named physics settings (`lads.physics.weather.SETTINGS`), optionally another detection
    rule or another spread of the sensor's detection curve."""
    key, value = preset(weather, severity)
    params = wx.settings_for(weather, settings)
    if detection is not None:
        params = replace(params, detection_threshold=detection)
    profile = load_profile("hdl64e")
    if spread_ln is not None:
        profile = replace(profile, detection=replace(profile.detection, spread_ln=spread_ln))
    src_range, lost, out_range, particle, ratios, materials, src_material = ([] for _ in range(7))
    for k, (points, labels) in enumerate(frames):
        rng = np.random.default_rng([k, list(PRESETS).index(weather), SEVERITIES.index(severity)])
        result = SIMULATE[weather](
            points[:, :3], points[:, 3], sensor=profile, rng=rng, params=params, **{key: value}
        )
        r_in = np.linalg.norm(points[:, :3].astype(np.float64), axis=1)
        is_lost = np.zeros(len(points), dtype=bool)
        is_lost[result.lost_index] = True
        src_range.append(r_in)
        src_material.append(material_index_for_labels(labels, "semantickitti"))
        lost.append(is_lost)
        out_range.append(np.linalg.norm(result.xyz.astype(np.float64), axis=1))
        particle.append(result.outcome == Outcome.PARTICLE)
        ratio, material = _attenuated_ratios(result, points, labels, profile)
        ratios.append(ratio)
        materials.append(material)
    r_in, is_lost = np.concatenate(src_range), np.concatenate(lost)
    r_out, is_particle = np.concatenate(out_range), np.concatenate(particle)
    per_material = _median_per_material(np.concatenate(ratios), np.concatenate(materials))
    return {
        key: value,
        "lost_share": round(float(is_lost.mean()), 5),
        "lost_share_per_source_range_bin": _share_per_bin(r_in, is_lost),
        "lost_share_per_material": _lost_per_material(is_lost, np.concatenate(src_material)),
        "particle_share_of_output": round(float(is_particle.mean()), 5),
        "particle_share_per_range_bin": _share_per_bin(r_out, is_particle),
        "attenuated_intensity_ratio_median_per_material": per_material,
    }


def _lost_per_material(
    is_lost: npt.NDArray[np.bool_], material: npt.NDArray[np.int64]
) -> dict[str, float]:
    """Share of each material's source points that the weather lost (materials with at
    least MIN_CLASS_POINTS points)."""
    names = material_names()
    return {
        names[m]: round(float(is_lost[material == m].mean()), 5)
        for m in np.unique(material)
        if (material == m).sum() >= MIN_CLASS_POINTS
    }


def _attenuated_ratios(
    result: Any, points: npt.NDArray[np.float32], labels: npt.NDArray[np.uint32], profile: Any
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Output / input reflectivity of a result's ATTENUATED points (input > 0) and their
    material indices."""
    att = result.outcome == Outcome.ATTENUATED
    src = result.source_index[att]
    before = profile.intensity.to_reflectivity(points[src, 3])
    after = profile.intensity.to_reflectivity(result.intensity[att])
    ok = before > 0
    return after[ok] / before[ok], material_index_for_labels(labels[src][ok], "semantickitti")


def _median_per_material(
    ratio: npt.NDArray[np.float64], material: npt.NDArray[np.int64]
) -> dict[str, float]:
    """Median ratio per material with at least MIN_CLASS_POINTS points."""
    names = material_names()
    return {
        names[m]: round(float(np.median(ratio[material == m])), 4)
        for m in np.unique(material)
        if (material == m).sum() >= MIN_CLASS_POINTS
    }


def _wet_ground(severity: str, frames: list[Any]) -> dict[str, Any]:
    """Wet ground at a severity's water film over the KITTI frames: lost share (of all points
    and of the ground points, per source range bin) and median intensity ratio per material."""
    key, film = preset("wet_ground", severity)
    profile = load_profile("hdl64e")
    ground, lost, src_range, ratios, materials = [], [], [], [], []
    for k, (points, labels) in enumerate(frames):
        rng = np.random.default_rng([k, len(WEATHERS), SEVERITIES.index(severity)])
        res = wet_ground(
            points[:, :3],
            points[:, 3],
            labels,
            "semantickitti",
            sensor=profile,
            rng=rng,
            params=WetGroundParams(film),
        )
        is_lost = np.zeros(len(points), dtype=bool)
        is_lost[res.lost_index] = True
        ground.append(wet_surface_for_labels(labels, "semantickitti")[0])
        lost.append(is_lost)
        src_range.append(np.linalg.norm(points[:, :3].astype(np.float64), axis=1))
        ratio, material = _attenuated_ratios(res, points, labels, profile)
        ratios.append(ratio)
        materials.append(material)
    is_ground, is_lost, r = np.concatenate(ground), np.concatenate(lost), np.concatenate(src_range)
    return {
        key: film,
        "lost_share": round(float(is_lost.mean()), 5),
        "lost_share_of_ground": round(float(is_lost[is_ground].mean()), 5),
        "ground_lost_share_per_source_range_bin": _share_per_bin(r[is_ground], is_lost[is_ground]),
        "wet_intensity_ratio_median_per_material": _median_per_material(
            np.concatenate(ratios), np.concatenate(materials)
        ),
    }


def _model_facts(frames: list[Any]) -> dict[str, Any]:
    """Numbers docs/physics.md quotes about the detection and wet-ground models: the share
    of KITTI returns stored with remission 0 per range bin (why a point is never taken as
    weaker than the detection limit), the fog echo over each profile's limit per preset
    visibility, and the wet/dry backscatter ratio of asphalt under a covering film."""
    r = np.concatenate([np.linalg.norm(p[:, :3].astype(np.float64), axis=1) for p, _ in frames])
    zero = np.concatenate([p[:, 3] == 0 for p, _ in frames])
    echo: dict[str, dict[str, float]] = {}
    for name in ("hdl64e", "hdl32e"):
        profile = load_profile(name)
        params = wx.FOG_DEFAULTS.resolved_for(profile)
        echo[name] = {}
        for severity in SEVERITIES:
            mor = preset("fog", severity)[1]
            alpha = extinction_from_visibility(mor)
            beta = backscatter_from_visibility(mor, params)
            _, power, _ = soft_return_peak(np.array([100.0]), alpha, beta, params)
            echo[name][f"mor_{mor:g}_m"] = round(float(power[0] / profile.detection.power), 3)
    degrees = (0.0, 60.0, 78.0, 87.0)
    ratio = wet_ratio(
        np.cos(np.radians(degrees)), np.full(4, 0.10), np.full(4, 1.0), WetGroundParams(1.2)
    )
    return {
        "kitti_zero_remission_share_per_range_bin": _share_per_bin(r, zero),
        "fog_echo_over_detection_limit": echo,
        "wet_over_dry_asphalt_1_2mm_by_incidence_deg": {
            f"{d:g}": round(float(g), 3) for d, g in zip(degrees, ratio, strict=True)
        },
        "water_internal_diffuse_reflectance": round(internal_diffuse_reflectance(WATER_N), 4),
    }


def _wads_reference() -> dict[str, Any]:
    r_all, snow = [], []
    for root in WADS_ROOTS:
        folder = SHARED_DATA / root / "sequences" / "36"
        for path in sorted((folder / "velodyne").glob("*.bin")):
            frame = wads.load_frame(path)
            _, first = np.unique(frame.points, axis=0, return_index=True)
            pts, lab = frame.points[first], frame.labels[first]
            r_all.append(np.linalg.norm(pts[:, :3].astype(np.float64), axis=1))
            snow.append(lab == wads.FALLING_SNOW)
    if not r_all:
        raise InputDataError(f"WADS frames missing under {SHARED_DATA} (wads, wads-more).")
    r, is_snow = np.concatenate(r_all), np.concatenate(snow)
    return {
        "frames": len(r_all),
        "falling_snow_share_of_unique_returns": round(float(is_snow.mean()), 5),
        "falling_snow_share_per_range_bin": _share_per_bin(r, is_snow),
    }


def _nuscenes_fog() -> dict[str, Any]:
    """Fog on real nuScenes frames (HDL-32E, RADIATE's sensor): returns per fired beam.

    nuScenes stores a point for nearly every firing (32 lasers x 1084 per 20 Hz sweep), about
    a quarter of them the vehicle's own roof within BODY_M; returns beyond BODY_M per firing
    are the share of fired beams that see the scene (lads.calibration.radiate_share, which
    also fits a RADIATE-like visibility).
    """
    folder = SHARED_DATA / "nuscenes-kittifmt"
    if not folder.is_dir():
        raise InputDataError(f"real nuScenes frames missing at {folder} (../shared/data).")
    reader = get_reader("nuscenes-kitti", folder)
    frames = [reader.read(item).points[:, :4].copy() for item in reader.items()[::NUSCENES_STRIDE]]
    profile = load_profile("hdl32e")
    out: dict[str, Any] = {
        "frames": len(frames),
        "firings_per_sweep": NUSCENES_FIRINGS,
        "returns_counted_beyond_m": BODY_M,
    }
    for visibility in NUSCENES_FOG_MOR_M:
        returned, echoes, ranges = [], [], []
        for k, points in enumerate(frames):
            rng = np.random.default_rng([k, int(visibility)])
            res = wx.fog(
                points[:, :3], points[:, 3], visibility_m=visibility, sensor=profile, rng=rng
            )
            r = np.linalg.norm(res.xyz.astype(np.float64), axis=1)
            scene = r >= BODY_M
            returned.append(int(scene.sum()) / NUSCENES_FIRINGS)
            echoes.append(float((res.outcome[scene] == Outcome.PARTICLE).mean()))
            ranges.append(r[scene])
        r = np.concatenate(ranges)
        counts = np.histogram(r, bins=np.asarray(RANGE_BINS_M))[0]
        out[f"mor_{visibility:g}_m"] = {
            "returns_per_fired_beam": round(float(np.mean(returned)), 4),
            "fog_echo_share_of_returns": round(float(np.mean(echoes)), 4),
            "share_of_returns_per_range_bin": [round(float(c / r.size), 5) for c in counts],
        }
    clear_r = [np.linalg.norm(p[:, :3].astype(np.float64), axis=1) for p in frames]
    clear_r = [r[r >= BODY_M] for r in clear_r]
    out["clear_returns_per_fired_beam"] = round(
        float(np.mean([r.size / NUSCENES_FIRINGS for r in clear_r])), 4
    )
    counts = np.histogram(np.concatenate(clear_r), bins=np.asarray(RANGE_BINS_M))[0]
    out["clear_share_of_returns_per_range_bin"] = [
        round(float(c / counts.sum()), 5) for c in counts
    ]
    return out


def _radiate_reference() -> dict[str, Any]:
    """RADIATE's foggy frames as lads.calibration.radiate_share counts them: returns beyond
    BODY_M per fired beam in the half of the sweep free of the vehicle's structure."""
    folder = SHARED_DATA / "radiate" / "tiny_foggy" / "velo_lidar"
    paths = sorted(folder.glob("*.csv"))
    if not paths:
        raise InputDataError(f"RADIATE foggy frames missing at {folder}.")
    profiles = [radiate_profile(radiate.load_frame(path)) for path in paths]
    return {
        "frames": len(paths),
        "returns_per_fired_beam": [round(p.share, 4) for p in profiles],
        "range_bins_m": [str(b) for b in SHARE_BINS_M],
        "share_of_returns_per_range_bin": [
            round(float(v), 5) for v in np.mean([p.per_bin for p in profiles], axis=0)
        ],
    }


def _figure(result: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lads.files import atomic_write_figure

    labels = _bin_labels()
    x = np.arange(len(labels))
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), sharey=False)
    for ax, weather in zip(axes, WEATHERS, strict=True):
        colours = ("tab:green", "tab:orange", "tab:red")
        for severity, colour in zip(SEVERITIES, colours, strict=True):
            row = result["simulated"][weather][severity]
            lost = [np.nan if v is None else v for v in row["lost_share_per_source_range_bin"]]
            part = [np.nan if v is None else v for v in row["particle_share_per_range_bin"]]
            ax.plot(x, lost, "-o", color=colour, label=f"{severity}: lost")
            ax.plot(x, part, "--s", color=colour, label=f"{severity}: particle returns")
        if weather == "snow":
            ref = result["references"]["wads_falling_snow"]["falling_snow_share_per_range_bin"]
            real = [np.nan if v is None else v for v in ref]
            ax.plot(x, real, ":k^", label="WADS real snow: share of returns")
        ax.set_title(f"{weather} on real SemanticKITTI frames")
        ax.set_xticks(x, labels, rotation=30)
        ax.set_ylabel("share of points in the range bin")
        ax.set_yscale("symlog", linthresh=1e-3)
        ax.set_ylim(bottom=0.0)
        ax.legend(fontsize=7)
    fog_ref = result["references"]["radiate_fog"]["returns_per_fired_beam"]
    axes[2].text(
        0.02,
        0.02,
        f"RADIATE real fog: {min(fog_ref):.2f}-{max(fog_ref):.2f} of fired beams return",
        transform=axes[2].transAxes,
        fontsize=8,
    )
    fig.tight_layout()
    atomic_write_figure(fig, path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    frames = _kitti_frames()
    simulated = {w: {s: _simulate(w, s, frames) for s in SEVERITIES} for w in WEATHERS}
    lisa = {
        w: {s: _simulate(w, s, frames, "lisa") for s in SEVERITIES} for w in wx.SETTINGS["lisa"]
    }
    # How much the default's loss owes to the assumed spread of the detection curve, and
    # what the frame-calibrated threshold (the default before the sensor's limit) gives.
    sensitivity = {
        w: {
            "frame_threshold": _simulate(w, "heavy", frames, detection="frame")["lost_share"],
            **{
                f"sensor_spread_ln_{s:g}": _simulate(w, "heavy", frames, spread_ln=s)["lost_share"]
                for s in SPREADS_LN
            },
        }
        for w in WEATHERS
    }
    result = {
        "what": "rain, snow and fog at each severity preset on labelled real SemanticKITTI "
        "frames (physics only, strongest return), beside WADS real snow and RADIATE real fog",
        "command": "python -m benchmarks.realism",
        "kitti_frames": len(frames),
        "range_bins_m": _bin_labels(),
        "kitti_points_per_range_bin": _points_per_bin(frames),
        "simulated": simulated,
        "simulated_lisa_settings": lisa,
        "wet_ground": {s: _wet_ground(s, frames) for s in SEVERITIES},
        "model_facts": _model_facts(frames),
        "heavy_lost_share_by_detection_rule": sensitivity,
        "references": {"wads_falling_snow": _wads_reference(), "radiate_fog": _radiate_reference()},
        "fog_on_real_nuscenes_hdl32e": _nuscenes_fog(),
        "note": "simulated shares are relative to the beams that returned in clear air; "
        "RADIATE's to every beam fired; the references are other sensors, places and "
        "strengths",
        "machine": machine_info(),
    }
    _figure(result, RESULTS / "realism.png")
    write_result("realism.json", result)
    return result


if __name__ == "__main__":
    main()
