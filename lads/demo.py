"""`make demo`: rain, snow and fog on a street scan lads ray-casts itself (no dataset needed).

Writes `<out>/weather_demo.png` (bird's-eye views coloured by outcome, and the range
distribution of particle returns) and `<out>/summary.json` (per weather: outcome counts,
extinction, particle-return range percentiles, run time).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from lads.physics import weather
from lads.physics.result import Outcome, WeatherResult
from lads.sensors.profile import load_profile
from lads.synthetic import synthetic_scan

SCENARIOS: tuple[tuple[str, str, dict[str, float]], ...] = (
    ("rain 25 mm/h", "rain", {"rate_mm_h": 25.0}),
    ("snow 10 mm/h", "snow", {"rate_mm_h": 10.0}),
    ("fog, visibility 50 m", "fog", {"visibility_m": 50.0}),
)
OUTCOME_COLOURS = {
    Outcome.KEPT: "#4a4a4a",
    Outcome.ATTENUATED: "#4a4a4a",
    Outcome.PARTICLE: "#e8112d",
}


def run_demo(out_dir: Path, *, sensor: str = "hdl64e", seed: int = 0) -> dict[str, Any]:
    """Simulate every scenario on one synthetic frame; write the figure and summary.

    Returns:
        The summary dict that is also written to `out_dir/summary.json`.
    """
    profile = load_profile(sensor)
    scan = synthetic_scan(profile, seed=seed)
    results: dict[str, WeatherResult] = {}
    summary: dict[str, Any] = {
        "sensor": profile.name,
        "seed": seed,
        "input_points": int(scan.xyz.shape[0]),
        "weather": {},
    }
    for title, name, kwargs in SCENARIOS:
        simulate = getattr(weather, name)
        # The first call builds the Mie and sampling tables (cached); time the second.
        simulate(scan.xyz, scan.intensity, sensor=profile, rng=np.random.default_rng(0), **kwargs)
        rng = np.random.default_rng([seed, len(results)])
        start = time.perf_counter()
        result = simulate(scan.xyz, scan.intensity, sensor=profile, rng=rng, **kwargs)
        elapsed_ms = 1e3 * (time.perf_counter() - start)
        results[title] = result
        particle_range = np.linalg.norm(result.xyz[result.outcome == Outcome.PARTICLE], axis=1)
        summary["weather"][title] = {
            **kwargs,
            "counts": result.counts(),
            "extinction_per_m": result.extinction_per_m,
            "two_way_transmission_at_50_m": float(np.exp(-2 * result.extinction_per_m * 50.0)),
            "particle_range_p5_p50_p95_m": (
                [round(float(v), 3) for v in np.percentile(particle_range, [5, 50, 95])]
                if particle_range.size
                else None
            ),
            "runtime_ms_after_warm_up": round(elapsed_ms, 2),
        }
    out_dir.mkdir(parents=True, exist_ok=True)
    _write_json(out_dir / "summary.json", summary)
    _plot(out_dir / "weather_demo.png", scan.xyz, results)
    return summary


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2) + "\n")
    tmp.replace(path)


def _plot(path: Path, clear_xyz: np.ndarray, results: dict[str, WeatherResult]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results) + 2, figsize=(5 * (len(results) + 2), 5))
    extent = 40.0

    def bev(ax: Any, xyz: np.ndarray, colour: Any, title: str) -> None:
        ax.scatter(xyz[:, 0], xyz[:, 1], s=0.2, c=colour, linewidths=0)
        ax.set_xlim(-extent, extent)
        ax.set_ylim(-extent, extent)
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("x (m)")

    bev(axes[0], clear_xyz, "#4a4a4a", f"clear ({clear_xyz.shape[0]:,} points)")
    axes[0].set_ylabel("y (m)")
    for ax, (title, result) in zip(axes[1:-1], results.items(), strict=True):
        colours = np.array([OUTCOME_COLOURS[Outcome(o)] for o in range(3)])[result.outcome]
        order = np.argsort(result.outcome == Outcome.PARTICLE, kind="stable")  # particles on top
        counts = result.counts()
        bev(ax, result.xyz[order], colours[order],
            f"{title}\nparticle {counts['particle']:,} · lost {counts['lost']:,}")  # fmt: skip
    hist_ax = axes[-1]
    bins = np.linspace(0.0, 30.0, 61)
    for title, result in results.items():
        r = np.linalg.norm(result.xyz[result.outcome == Outcome.PARTICLE], axis=1)
        hist_ax.hist(r, bins=bins, histtype="step", label=f"{title} ({r.size:,})")
    hist_ax.set_xlabel("range of particle / fog returns (m)")
    hist_ax.set_ylabel("returns per 0.5 m")
    hist_ax.legend(fontsize=8)
    hist_ax.set_title("where weather returns appear")
    fig.tight_layout()
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("demo_output"))
    parser.add_argument("--sensor", default="hdl64e")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    summary = run_demo(args.out, sensor=args.sensor, seed=args.seed)
    lines = [f"lads demo: {summary['input_points']:,} synthetic {summary['sensor']} points"]
    for title, info in summary["weather"].items():
        c = info["counts"]
        lines.append(
            f"  {title:22s} attenuated {c['attenuated']:7,}  particle {c['particle']:6,}  "
            f"lost {c['lost']:6,}  ({info['runtime_ms_after_warm_up']:.1f} ms)"
        )
    lines.append(f"wrote {args.out / 'weather_demo.png'} and {args.out / 'summary.json'}")
    import sys

    sys.stdout.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
