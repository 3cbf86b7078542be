"""Simulated vs real falling snow (WADS seq 36, label 110): fitted knobs vs LISA settings.

    .venv/bin/python -m benchmarks.wads_snow            # fit (about 3-4 min on one core)
    .venv/bin/python -m benchmarks.wads_snow --no-fit   # evaluate the shipped knobs only

Writes benchmarks/results/wads_snow.json and wads_snow.png. Fit on frames 042223 + 042224,
held-out test on 042225, and all three pooled (only three labelled frames exist here: the
held-out frame is 0.1 s later in the same scene, so it tests seed/frame noise, not scenes).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict
from typing import Any

import numpy as np

from benchmarks.common import RESULTS, SHARED_DATA, machine_info, write_result
from lads.calibration import wads as W
from lads.errors import InputDataError
from lads.physics.weather import SNOW_DEFAULTS

SEQUENCE = SHARED_DATA / "wads" / "sequences" / "36"
FRAMES = ("042223", "042224", "042225")
FIT, TEST = (0, 1), (2,)
EVAL_SEEDS = (0, 1, 2)


def _settings(fitted: W.SnowKnobs, dual: W.SnowKnobs) -> dict[str, Any]:
    return {
        "ours_strongest": ("strongest", fitted.params()),
        "ours_dual_emulation": ("dual", dual.params()),
        "lisa_paper_strongest": ("strongest", W.LISA_SNOW),
        "lisa_paper_dual_emulation": ("dual", W.LISA_SNOW),
        "lisa_hahner_strongest": ("strongest", W.LISA_HAHNER_SNOW),
        "shipped_snow_defaults_strongest": ("strongest", SNOW_DEFAULTS),
    }


def _evaluate_all(scenes, fitted, dual) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, (mode, params) in _settings(fitted, dual).items():
        out[name] = {
            split: W.evaluate([scenes[i] for i in idx], params, mode=mode, seeds=EVAL_SEEDS)
            for split, idx in (("fit", FIT), ("held_out", TEST), ("all", (0, 1, 2)))
        }
        out[name]["mode"] = mode
    return out


def _figure(scenes, fitted: W.SnowKnobs, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bins = np.arange(0, 20.25, 0.25)
    real = np.concatenate([s.snow_range_m for s in scenes])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.hist(real, bins, density=True, histtype="stepfilled", alpha=0.35, color="k",
            label=f"WADS label 110 (n={real.size})")  # fmt: skip
    for label, mode, params, color in (
        ("ours (strongest, fitted)", "strongest", fitted.params(), "C0"),
        ("LISA settings (strongest)", "strongest", W.LISA_SNOW, "C3"),
    ):
        sim = np.concatenate([
            W.simulate(s, params, rate_mm_h=W.ASSUMED_RATE_MM_H,
                       rng=np.random.default_rng([0, k]), mode=mode).range_m
            for k, s in enumerate(scenes)
        ])  # fmt: skip
        ax.hist(sim, bins, density=True, histtype="step", lw=1.5, color=color,
                label=f"{label} (n={sim.size})")  # fmt: skip
    ax.set_xlabel("range of falling-snow return (m)")
    ax.set_ylabel("density")
    ax.set_title(f"WADS seq 36, 3 frames; snowfall {W.ASSUMED_RATE_MM_H} mm/h (assumed)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-fit", action="store_true", help="evaluate the shipped knobs")
    args = parser.parse_args(argv or [])
    if not SEQUENCE.is_dir():
        raise InputDataError(f"WADS sample missing at {SEQUENCE} (see ../shared/data).")
    start = time.perf_counter()
    scenes = [W.scene_from_frame(f) for f in W.load_sequence(SEQUENCE, FRAMES)]
    fit_scenes = [scenes[i] for i in FIT]
    fits: dict[str, Any] = {}
    fitted, dual = W.FITTED_SNOW_KNOBS, W.FITTED_DUAL_KNOBS
    if not args.no_fit:
        for key, mode, with_threshold in (
            ("strongest_auto_threshold", "strongest", False),
            ("dual_absolute_threshold", "dual", True),
        ):
            t = time.perf_counter()
            res = W.fit(fit_scenes, mode=mode, fit_threshold=with_threshold)
            fits[key] = {
                "knobs": asdict(res.knobs), "loss": round(res.loss, 4),
                "grid_start": asdict(res.grid_best), "grid_loss": round(res.grid_loss, 4),
                "evaluations": res.evaluations, "seconds": round(time.perf_counter() - t, 1),
            }  # fmt: skip
        fitted = W.SnowKnobs(**fits["strongest_auto_threshold"]["knobs"])
        dual = W.SnowKnobs(**fits["dual_absolute_threshold"]["knobs"])
    results = _evaluate_all(scenes, fitted, dual)
    sensitivity = W.rate_sensitivity(fit_scenes, fitted, (1.0, 2.5, 5.0), mode="strongest")
    payload = {
        "description": "Falling snow simulated on WADS clear scenes (label 110 removed) vs "
        "the real label-110 points in front of a recorded target. ks_range: two-sample KS "
        "distance of ranges; fraction: flakes / (clear points + flakes).",
        "data": {
            "sequence": str(SEQUENCE.relative_to(SHARED_DATA.parent)),
            "frames": FRAMES,
            "fit_frames": [FRAMES[i] for i in FIT],
            "held_out_frames": [FRAMES[i] for i in TEST],
        },  # fmt: skip
        "real": {s.name: s.real for s in scenes},
        "rate_assumption": {
            "rate_mm_h_water_equivalent": W.ASSUMED_RATE_MM_H,
            "why": "WADS does not record the snowfall rate per frame; 2.5 mm/h w.e. (~2.5 cm/h "
            "of snow) is a 'heavy snow' rate. The flake count scales with rate and with "
            "rho_p / P_min alike, so the fitted knobs are conditional on it (see "
            "rate_sensitivity).",
        },
        "knobs_recommended_for_SNOW_DEFAULTS": asdict(fitted),
        "knobs_dual_return_emulation": asdict(dual),
        "fits": fits,
        "results": results,
        "rate_sensitivity_strongest": sensitivity,
        "limitations": [
            "Only 3 labelled frames of one scene, 0.1 s apart: the held-out frame tests frame "
            "noise, not generalisation to other scenes, rates or sensors.",
            "WADS is dual-return (measured: 42 % duplicate rows, snow rows 30 % duplicated vs "
            "86 % for others); weather.snow() models one strongest return. The recommended "
            "knobs are an effective fit through snow(); under the dual-return emulation they "
            "give ~7x too many flakes. The dual fit needs an absolute threshold (~1e-5) that "
            "8 % of the clear WADS returns fall below.",
            "Flakes with no target behind (duplicated 110 rows, ~17 % of unique snow points, "
            "mostly upward beams) are not simulated: the clear scene has no beam there.",
            "Snowfall rate unknown (nuisance, fixed at an assumption).",
            "Intensity: WADS encoding of low reflectivities (0 = below 0.5 %) limits the "
            "intensity comparison to 'zero or not'.",
        ],
        "seconds": round(time.perf_counter() - start, 1),
        "machine": machine_info(),
    }
    write_result("wads_snow.json", payload)
    _figure(scenes, fitted, RESULTS / "wads_snow.png")
    return payload


if __name__ == "__main__":
    import sys

    out = main(sys.argv[1:])
    r = out["results"]
    for name in ("ours_strongest", "ours_dual_emulation", "lisa_paper_strongest"):
        print(name, {k: r[name][k]["ks_range"] for k in ("fit", "held_out", "all")},
              "fraction ratio", r[name]["all"]["fraction_ratio"])  # fmt: skip
