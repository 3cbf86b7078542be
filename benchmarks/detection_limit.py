"""Sensor detection limits measured from real clear frames (lads.sensors.detection_fit).

Run: .venv/bin/python -m benchmarks.detection_limit
     (writes benchmarks/results/detection_limit.json and detection_limit.png)

The HDL-32E (nuScenes, calibrated reflectivity) is fitted on scene-0002 (nuscenes-kittifmt,
40 keyframes) and again, as a check on another place, on scene-0001 (40 keyframes); the
hdl32e profile holds the scene-0002 fit. KITTI's HDL-64E remission and WADS's intensity are
fitted the same way to show why their profiles do not take the estimator: they are not
calibrated reflectivity, and the "limits" they give are far below any datasheet.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from benchmarks.common import RESULTS, SHARED_DATA, machine_info, write_result
from lads.errors import InputDataError
from lads.readers import get_reader
from lads.sensors.detection_fit import FIT_MIN_RANGE_M, DetectionFit, fit_detection_limit
from lads.sensors.profile import load_profile

Scan = tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]]
# Sources whose intensity is not calibrated reflectivity: fitted only to show it.
UNCALIBRATED = (("semantickitti", "semantickitti-seqx", "hdl64e"), ("wads", "wads", "wads64"))


def _ranges_and_intensity(reader: Any) -> Scan:
    points = np.concatenate([reader.read(item).points[:, :4] for item in reader.items()])
    return np.linalg.norm(points[:, :3].astype(np.float64), axis=1), points[:, 3].copy()


def nuscenes_scenes() -> list[Scan]:
    """(ranges m, intensities 0-255) of all keyframes of scene-0002, then of scene-0001."""
    from tests.real_trees import real_nuscenes_scene0001

    folder = SHARED_DATA / "nuscenes-kittifmt"
    if not folder.is_dir():
        raise InputDataError(f"real nuScenes frames missing at {folder} (../shared/data).")
    scans = [_ranges_and_intensity(get_reader("nuscenes-kitti", folder))]
    with tempfile.TemporaryDirectory() as tmp:
        root = real_nuscenes_scene0001(Path(tmp))
        scans.append(_ranges_and_intensity(get_reader("nuscenes", root)))
    return scans


def _row(fit: DetectionFit, profile_name: str) -> dict[str, Any]:
    profile = load_profile(profile_name).detection
    return {
        "limit_power": float(f"{fit.limit_power:.4g}"),
        "spread_ln": round(fit.spread_ln, 4),
        "range_10pct_m": round(fit.range_for(0.1), 1),
        "range_80pct_m": round(fit.range_for(0.8), 1),
        "returns": fit.returns,
        "nll_per_return": round(fit.nll_per_return, 4),
        "profile_limit_power": float(f"{profile.power:.4g}"),
        "profile_spread_ln": profile.spread_ln,
    }


def figure(scan: Scan, fit: DetectionFit, path: Path) -> None:
    """Reflectivity against range of scene-0002's returns, with the fitted detection curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, intensity = scan
    rho = np.maximum(intensity / 100.0, 0.005)
    keep = (r >= 5.0) & (rho <= 1.0)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.hist2d(
        r[keep],
        rho[keep],
        bins=[np.arange(5, 106, 1.0), np.logspace(-2.4, 0, 60)],
        cmap="Greys",
        norm=matplotlib.colors.LogNorm(),
    )
    ax.set_yscale("log")
    grid = np.linspace(FIT_MIN_RANGE_M, 105, 100)
    for z, style in ((0.0, "r-"), (-1.2816, "r:"), (1.2816, "r:")):
        rho_at = fit.limit_power * np.exp(z * fit.spread_ln) * grid**2
        ax.plot(grid, rho_at, style, lw=1.2)
    ax.plot([], [], "r-", label=f"fit: 50 % detected (P_lim = {fit.limit_power:.2g} / m^2)")
    ax.plot([], [], "r:", label=f"10 % and 90 % detected (s = {fit.spread_ln:.2f})")
    ax.set(
        xlabel="range, m",
        ylabel="reported reflectivity",
        ylim=(0.004, 1.0),
        title="nuScenes HDL-32E, scene-0002: returns and the fitted limit",
    )
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> dict[str, Any]:
    start = time.perf_counter()
    scenes = nuscenes_scenes()
    fits = [fit_detection_limit(r, i, load_profile("hdl32e")) for r, i in scenes]
    uncalibrated = {}
    for reader_name, folder, profile_name in UNCALIBRATED:
        if not (SHARED_DATA / folder).is_dir():
            raise InputDataError(f"real frames missing at {SHARED_DATA / folder}.")
        r, i = _ranges_and_intensity(get_reader(reader_name, SHARED_DATA / folder))
        fit = fit_detection_limit(r, i, load_profile(profile_name))
        uncalibrated[f"{folder} ({profile_name})"] = _row(fit, profile_name)
    payload = {
        "what": __doc__.strip().splitlines()[0],
        "method": "lads.sensors.detection_fit (docs/physics.md §9.7): maximum likelihood of "
        "each return's reflectivity level given its range, from "
        f"{FIT_MIN_RANGE_M:g} m to the profile's max range",
        "hdl32e_nuscenes_scene_0002_fit": _row(fits[0], "hdl32e"),
        "hdl32e_nuscenes_scene_0001_check": _row(fits[1], "hdl32e"),
        "not_calibrated_reflectivity": uncalibrated,
        "seconds": round(time.perf_counter() - start, 1),
        "machine": machine_info(),
    }
    write_result("detection_limit.json", payload)
    figure(scenes[0], fits[0], RESULTS / "detection_limit.png")
    return payload


if __name__ == "__main__":
    out = main()
    for key in ("hdl32e_nuscenes_scene_0002_fit", "hdl32e_nuscenes_scene_0001_check"):
        print(key, out[key])
    for key, row in out["not_calibrated_reflectivity"].items():
        print(key, row)
