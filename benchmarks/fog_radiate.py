"""Fog model vs real fog (RADIATE fog_6_0, HDL-32E): what the three sample frames can show.

    .venv/bin/python -m benchmarks.fog_radiate

Writes benchmarks/results/fog_radiate.json. No clear-weather twin and no visibility record
exist for these frames, so only a bound is computed: the smallest visibility (MOR) at which
our fog model, run on the frame's clean half (azimuth 0..180 deg) with the frame's own
detection threshold, produces no more near (< 3 m) fog returns than the real frame shows,
for several overlap ranges R2 and both backscatter models (lads.calibration.radiate).

Then a RADIATE-like fog (lads.calibration.radiate_share): fog on real clear nuScenes frames
(the same HDL-32E), its visibility fitted to frame 000018 by return share alone and by range
profile alone, each fit scored on frames 000019-20 by both measures; figure
benchmarks/results/fog_radiate.png.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from benchmarks.common import RESULTS, SHARED_DATA, machine_info, write_result
from benchmarks.realism import NUSCENES_FIRINGS, NUSCENES_STRIDE
from lads.calibration import radiate as R
from lads.calibration import radiate_share as S
from lads.errors import InputDataError
from lads.physics import weather as wx
from lads.physics.fog import FogParams
from lads.physics.severity import preset
from lads.physics.weather import FAINT_FULL_M, FAINT_ONSET_M, FOG_DEFAULTS
from lads.physics.wet_ground import WetGroundParams, wet_ground
from lads.readers import get_reader, label_set_for
from lads.sensors.profile import load_profile

FOLDER = SHARED_DATA / "radiate" / "tiny_foggy" / "velo_lidar"
FRAMES = ("000018", "000019", "000020")
OVERLAP_FULL_M = (1.0, 2.0, 3.0, 5.0, 8.0)
FIT_FRAME = "000018"  # the other frames score the fit
NUSCENES = SHARED_DATA / "nuscenes-kittifmt"


def radiate_like_fog(frames: list[R.RadiateFrame]) -> dict[str, Any]:
    """Visibility fitted to one RADIATE frame by share or by range profile, scored on the
    others by both (lads.calibration.radiate_share), over all channels and over the upper
    band that neither vehicle's structure reaches."""
    if not NUSCENES.is_dir():
        raise InputDataError(f"real nuScenes frames missing at {NUSCENES} (../shared/data).")
    reader = get_reader("nuscenes-kitti", NUSCENES)
    clear, labels = [], []
    for item in reader.items()[::NUSCENES_STRIDE]:
        frame = reader.read(item)
        clear.append((frame.points[:, :3].copy(), frame.points[:, 3].copy()))
        labels.append(frame.labels)
    sensor = load_profile(R.SENSOR)
    per_channel = NUSCENES_FIRINGS // sensor.channels
    curves = S.simulated_curves(clear, per_channel, sensor, ("all", "upper", "steep"))
    like = _fits(frames, curves["all"], "all")
    fits = like["fits"]
    return {
        "near_ground": _near_ground(frames, clear, labels, fits, sensor),
        "clear_frames": {
            "folder": "nuscenes-kittifmt",
            "frames": len(clear),
            "stride": NUSCENES_STRIDE,
            "firings_per_sweep": NUSCENES_FIRINGS,
        },
        "range_bins_m": [str(b) for b in S.RANGE_BINS_M],
        **like,
        "upper_channels": {
            "elevation_from_deg": S.NEAR_GROUND_ELEVATION_DEG[1],
            "radiate_share_per_30_deg_of_the_clean_half": _sector_shares(frames, sensor),
            "nuscenes_clear": S.ReturnProfile.mean(
                [S.band_profile(x, per_channel, sensor, "upper") for x, _ in clear]
            ).as_dict(),
            **_fits(frames, curves["upper"], "upper"),
        },
        "steep_channels": {
            "elevation_to_deg": S.NEAR_GROUND_ELEVATION_DEG[0],
            "radiate_clean_half": [round(S.radiate_profile(f, "steep").share, 4) for f in frames],
            "nuscenes_clear": round(
                S.ReturnProfile.mean(
                    [S.band_profile(x, per_channel, sensor, "steep") for x, _ in clear]
                ).share,
                4,
            ),
            "nuscenes_fog_per_visibility_m": {
                f"{mor:g}": round(p.share, 4) for mor, p in curves["steep"].items()
            },
        },
    }


def _sector_shares(frames: list[R.RadiateFrame], sensor: Any) -> dict[str, list[float]]:
    """Returns beyond BODY_M per fired upper-band beam in each 30 deg sector of RADIATE's
    clean half, per frame (sector start, deg -> shares)."""
    channels = S.band_channels(sensor, "upper")
    lo, hi = R.CLEAN_AZIMUTH_DEG
    edges = np.arange(lo, hi + 1.0, 30.0)
    firings = R.FIRINGS_PER_SWEEP * 30.0 / 360.0 * channels.size
    out: dict[str, list[float]] = {f"{a:g}": [] for a in edges[:-1]}
    for frame in frames:
        xyz = S.clean_half(frame)
        xyz = xyz[np.linalg.norm(xyz, axis=1) >= S.BODY_M]
        xyz = xyz[np.isin(sensor.channel_of(xyz), channels)]
        counts = np.histogram(np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])), edges)[0]
        for a, c in zip(edges[:-1], counts, strict=True):
            out[f"{a:g}"].append(round(float(c / firings), 3))
    return out


def _fits(
    frames: list[R.RadiateFrame], curve: dict[float, S.ReturnProfile], band: str
) -> dict[str, Any]:
    """RADIATE's profiles over `band`, the simulated curve and both fits on FIT_FRAME."""
    real = {f.name: S.radiate_profile(f, band) for f in frames}
    fits = {}
    for by in S.FIT_MEASURES:
        mor = S.fit_visibility(real[FIT_FRAME], curve, by)
        fits[f"by_{by}"] = {
            "visibility_m": mor,
            "simulated": curve[mor].as_dict(),
            "held_out": {
                name: {
                    "returns_per_fired_beam_error": round(curve[mor].share - p.share, 4),
                    "range_profile_distance": round(S.profile_distance(curve[mor], p), 4),
                }
                for name, p in real.items()
                if name != FIT_FRAME
            },
        }
    return {
        "real_clean_half": {name: p.as_dict() for name, p in real.items()},
        "simulated_per_visibility_m": {f"{mor:g}": p.as_dict() for mor, p in curve.items()},
        "fit_frame": FIT_FRAME,
        "fits": fits,
    }


def _near_ground(
    frames: list[R.RadiateFrame],
    clear: list[tuple[Any, Any]],
    labels: list[Any],
    fits: dict[str, Any],
    sensor: Any,
) -> dict[str, Any]:
    """Returns per fired beam of the near-ground channels (road at 5-9 m): RADIATE's clean
    half, and clear nuScenes frames as they are, in the fitted fogs, and in the by-profile
    fog after the heaviest wet-road preset (the film model of docs/physics.md §8.2)."""
    half, full = R.FIRINGS_PER_SWEEP // 2, NUSCENES_FIRINGS // 32
    clean = [S.clean_half(f) for f in frames]
    film_mm = preset("wet_ground", "heavy")[1]
    film, label_set = WetGroundParams(film_mm), label_set_for("nuscenes-kitti")

    def simulated(mor: float, wet: bool) -> float:
        shares = []
        for k, ((xyz, intensity), lab) in enumerate(zip(clear, labels, strict=True)):
            rng = np.random.default_rng([k, int(mor), int(wet)])
            if wet:
                road = wet_ground(
                    xyz, intensity, lab, label_set, sensor=sensor, rng=rng, params=film
                )
                xyz, intensity = road.xyz, road.intensity
            out = wx.fog(xyz, intensity, visibility_m=mor, sensor=sensor, rng=rng)
            shares.append(S.near_ground_share(out.xyz, full, sensor))
        return round(float(np.mean(shares)), 4)

    mor_profile = fits["by_profile"]["visibility_m"]
    return {
        "elevation_window_deg": list(S.NEAR_GROUND_ELEVATION_DEG),
        "radiate_clean_half": [round(S.near_ground_share(x, half, sensor), 4) for x in clean],
        "nuscenes_clear": round(
            float(np.mean([S.near_ground_share(x, full, sensor) for x, _ in clear])), 4
        ),
        **{
            f"nuscenes_fog_mor_{fit['visibility_m']:g}_m": simulated(fit["visibility_m"], False)
            for fit in fits.values()
        },
        f"nuscenes_fog_mor_{mor_profile:g}_m_wet_road_{film_mm:g}_mm": simulated(mor_profile, True),
    }


def _like_finding(like: dict[str, Any]) -> str:
    """What the two visibility fits say, in words, from their numbers."""
    by_share, by_profile = like["fits"]["by_share"], like["fits"]["by_profile"]
    near = by_share["simulated"]["share_per_range_bin"][0]
    real = like["real_clean_half"][FIT_FRAME]
    ground = like["near_ground"]
    lo, hi = ground["elevation_window_deg"]
    fog_ground = ground[f"nuscenes_fog_mor_{by_profile['visibility_m']:g}_m"]
    wet_ground_share = next(v for k, v in ground.items() if "wet_road" in k)
    return (
        "RADIATE-like fog (radiate_like_fog): fog on real clear nuScenes HDL-32E frames matches "
        f"RADIATE's return share ({real['returns_per_fired_beam']:.2f} of fired beams beyond "
        f"{S.BODY_M} m in the clean half) at MOR {by_share['visibility_m']:g} m, where "
        f"{near:.0%} of the returns lie within 5 m (RADIATE {real['share_per_range_bin'][0]:.0%}); "
        f"it comes closest to RADIATE's range profile at MOR {by_profile['visibility_m']:g} m, "
        f"where {by_profile['simulated']['returns_per_fired_beam']:.2f} of the beams return. "
        f"The near-ground channels ({lo:g} to {hi:g} deg, road at 5-9 m) return on "
        f"{min(ground['radiate_clean_half']):.2f}-{max(ground['radiate_clean_half']):.2f} of "
        f"their firings in RADIATE, {ground['nuscenes_clear']:.2f} on clear nuScenes frames, "
        f"{fog_ground:.2f} in the by-profile fog and {wet_ground_share:.2f} with the heaviest "
        "wet-road preset added: neither fog nor the film model takes the near road away, and "
        "RADIATE shows no fog echoes while keeping walls and cars at 10-25 m. Candidates, not "
        "decided by three frames: a wet road far darker at grazing incidence than the film "
        "model (a mirror-like film), a receiver that suppresses faint near echoes, or "
        "structure of the recording vehicle beyond the azimuths set aside."
    )


def _upper_finding(like: dict[str, Any]) -> str:
    """What the fits over the upper band say, beside the steep channels' returns."""
    upper, steep = like["upper_channels"], like["steep_channels"]
    by_share, by_profile = upper["fits"]["by_share"], upper["fits"]["by_profile"]
    real = upper["real_clean_half"][FIT_FRAME]
    held = [h["range_profile_distance"] for h in by_profile["held_out"].values()]
    fogged = steep["nuscenes_fog_per_visibility_m"]
    fitted = fogged[f"{by_profile['visibility_m']:g}"]
    sectors = upper["radiate_share_per_30_deg_of_the_clean_half"]
    empty = min(sectors, key=lambda a: max(sectors[a]))
    return (
        f"Channels at or below {steep['elevation_to_deg']:g} deg (road within 5 m) return on "
        f"{min(steep['radiate_clean_half']):.2f}-{max(steep['radiate_clean_half']):.2f} of their "
        f"firings in RADIATE's clean half and {steep['nuscenes_clear']:.2f} in clear nuScenes "
        f"frames (their own vehicle takes the rest), {fitted:.2f} "
        f"in the fog fitted by profile and {min(fogged.values()):.2f} in the densest fog tried: "
        "fog thin enough to keep RADIATE's walls at 10-25 m leaves a road 3-5 m away, so the "
        "recording vehicle blocks these beams in the clean half too. Over the upper band "
        f"(from {upper['elevation_from_deg']:g} deg), which neither vehicle reaches, RADIATE "
        f"returns on {real['returns_per_fired_beam']:.2f} of the beams; the range profile is "
        f"matched at MOR {by_profile['visibility_m']:g} m (distance "
        f"{' and '.join(f'{h:.3f}' for h in held)} on the held-out frames), where "
        f"{by_profile['simulated']['returns_per_fired_beam']:.2f} of the beams return (clear "
        f"nuScenes {upper['nuscenes_clear']['returns_per_fired_beam']:.2f}); the share alone "
        f"is matched at MOR {by_share['visibility_m']:g} m with "
        f"{by_share['simulated']['share_per_range_bin'][0]:.0%} of the returns within 5 m "
        f"(RADIATE {real['share_per_range_bin'][0]:.0%}). The remaining gap in share is beams "
        "that return nothing at all in RADIATE, whole azimuth sectors up to the highest "
        f"channels included (the {empty}-{float(empty) + 30:g} deg sector: "
        f"{max(sectors[empty]):.2f} or less of its upper beams return): open space or "
        "structure, which three frames of one place cannot tell apart from fog."
    )


def figure(result: dict[str, Any], path: Any) -> None:
    """Return share vs visibility beside RADIATE's (all channels and the upper band), and the
    range profiles of both fits for each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    upper = result["upper_channels"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for part, name, colour in ((result, "all channels", "C0"), (upper, "upper band", "C3")):
        sim = part["simulated_per_visibility_m"]
        axes[0].semilogx(
            [float(m) for m in sim],
            [sim[m]["returns_per_fired_beam"] for m in sim],
            "o-",
            color=colour,
            label=f"fog on real nuScenes frames, {name}",
        )
        for p in part["real_clean_half"].values():
            axes[0].axhline(p["returns_per_fired_beam"], color=colour, lw=0.8, ls=":")
    axes[0].axhline(float("nan"), color="k", lw=0.8, ls=":", label="RADIATE fog_6_0 (3 frames)")
    axes[0].set(
        xlabel="visibility (MOR), m",
        ylim=(0, 1),
        ylabel=f"returns per fired beam (beyond {S.BODY_M} m)",
    )
    axes[0].legend(fontsize=8)
    band = f"upper band (from {upper['elevation_from_deg']:g} deg)"
    for ax, part, title in ((axes[1], result, "all channels"), (axes[2], upper, band)):
        _profiles_panel(ax, result["range_bins_m"], part, title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _profiles_panel(ax: Any, bins: list[str], part: dict[str, Any], title: str) -> None:
    """RADIATE's range profile on the fit frame beside each fit's simulated one."""
    labels = [f"{a}-{b}" for a, b in zip(bins[:-1], bins[1:], strict=True)]
    x = range(len(labels))
    real = part["real_clean_half"][part["fit_frame"]]["share_per_range_bin"]
    ax.plot(x, real, "ks-", label=f"RADIATE {part['fit_frame']}")
    for key, fit in part["fits"].items():
        label = f"fitted {key.replace('_', ' ')}: MOR {fit['visibility_m']:g} m"
        ax.plot(x, fit["simulated"]["share_per_range_bin"], "o--", label=label)
    ax.set_xticks(list(x), labels, fontsize=8)
    ax.set(xlabel="range bin, m", ylabel="share of returns", title=title)
    ax.legend(fontsize=8)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    if not FOLDER.is_dir():
        raise InputDataError(f"RADIATE sample missing at {FOLDER} (see ../shared/data).")
    start = time.perf_counter()
    frames = [R.load_frame(FOLDER / f"{n}.csv") for n in FRAMES]
    bounds = []
    for r2 in OVERLAP_FULL_M:
        for model in ("mie", "hahner"):
            params = FogParams(
                overlap_start_m=min(0.9, r2), overlap_full_m=r2, backscatter_model=model
            )
            per_frame = [R.visibility_bound(f, params=params) for f in frames]
            bounds.append(
                {
                    "overlap_full_m": r2,
                    "backscatter_model": model,
                    "min_visibility_consistent_m": [
                        b["min_visibility_consistent_m"] for b in per_frame
                    ],
                    "curve_frame_000018": per_frame[0]["curve"],
                }
            )
    shipped = [R.visibility_bound(f, params=FOG_DEFAULTS) for f in frames]
    like = radiate_like_fog(frames)
    bounds.append(
        {
            "overlap_full_m": FOG_DEFAULTS.overlap_full_m,
            "backscatter_model": "mie",
            "shipped_defaults": True,
            "min_visibility_consistent_m": [b["min_visibility_consistent_m"] for b in shipped],
            "curve_frame_000018": shipped[0]["curve"],
        }
    )
    payload = {
        "description": __doc__.strip().splitlines()[0],
        "data": {
            "folder": str(FOLDER.relative_to(SHARED_DATA.parent)),
            "frames": FRAMES,
            "meta": "fog_6_0 (RADIATE test set); no visibility recorded",
        },
        "real": {f.name: R.frame_stats(f) for f in frames},
        "detection_threshold_per_frame": {f.name: R.frame_threshold(f) for f in frames},
        "visibility_bounds": bounds,
        "radiate_like_fog": like,
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
            "upper bound on the sensor's), not the default rule (the HDL-32E profile's "
            "detection limit, docs/physics.md 9.7).",
            _like_finding(like),
            _upper_finding(like),
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
    figure(payload["radiate_like_fog"], RESULTS / "fog_radiate.png")
    return payload


if __name__ == "__main__":
    out = main()
    for b in out["visibility_bounds"]:
        print(b["overlap_full_m"], b["backscatter_model"], b["min_visibility_consistent_m"])
