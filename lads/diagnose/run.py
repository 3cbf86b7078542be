"""`lads diagnose`: trees in, report.json / report.md / figures (and a corrected tree) out.

The runner owns the I/O; the analysis (`analysis.diagnose_design`) and the localisation are
pure functions of the beam table and a generator seeded from --seed.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from lads.diagnose.config import CONFIG
from lads.diagnose.data.beams import paired_table, unpaired_tables
from lads.diagnose.data.table import BeamTable
from lads.diagnose.data.trees import open_trees
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.from_table import paired_design, unpaired_design
from lads.diagnose.output import figures
from lads.diagnose.output.corrected import write_corrected
from lads.diagnose.output.report import build_report, write_report
from lads.diagnose.verdict.analysis import PHASES, Diagnosis, Settings, diagnose_design
from lads.diagnose.where.localize import localize, to_json
from lads.errors import DiagnoseError

MIN_ROWS = CONFIG.verdict.min_rows
MIN_GROUPS = CONFIG.verdict.min_groups
LOCALIZE_BOOT = CONFIG.localize.bootstrap
PAIRED_SHARE_WARN = CONFIG.verdict.paired_share_warn


def _rng(seed: int, what: str) -> np.random.Generator:
    digest = hashlib.sha256(f"lads-diagnose/{seed}/{what}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def diagnose(
    sim_root: Path,
    real_root: Path,
    source: str,
    out: Path,
    *,
    paired: bool = True,
    seed: int = 0,
    write_corrected_to: Path | None = None,
    settings: Settings | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Run one diagnosis and write its report; returns the report document.

    Raises:
        DiagnoseError: trees that do not correspond or hold another sensor (see
            `trees.open_trees`), too few beams or groups to fit, or constant intensities.
    """
    _check_outside(out, "--out", sim_root, real_root)
    if write_corrected_to is not None:
        _check_outside(Path(write_corrected_to), "--write-corrected", sim_root, real_root)
    # Every array here is small: a second BLAS thread only spins (it doubled the CPU time of
    # a run and gained no wall time), and it starves the fit workers of `settings.jobs`.
    with threadpool_limits(limits=1):
        return _diagnose(
            sim_root,
            real_root,
            source,
            out,
            paired=paired,
            seed=seed,
            write_corrected_to=write_corrected_to,
            settings=settings or Settings(),
            progress=progress,
        )


def _diagnose(
    sim_root: Path,
    real_root: Path,
    source: str,
    out: Path,
    *,
    paired: bool,
    seed: int,
    write_corrected_to: Path | None,
    settings: Settings,
    progress: bool,
) -> dict[str, Any]:
    torch.set_num_threads(1)  # fits are small; one thread keeps results identical everywhere
    pair = open_trees(sim_root, real_root, source, paired=paired)
    sim_table = None
    if paired:
        table = paired_table(pair, progress=progress)
        design = paired_design(table)
    else:
        sim_table, table = unpaired_tables(pair, progress=progress)
        design = unpaired_design(sim_table, table)
    _check_fit_data(design, sim_root, real_root)
    steps = ("localise", *PHASES, "localise after", "figures and report")
    bar, step = _step_bar(len(steps), progress)
    with bar:
        step(steps[0])
        residual_before = _row_residual(table, design, None)
        loc_before = localize(
            table, residual_before, rng=_rng(seed, "localize"), n_boot=LOCALIZE_BOOT
        )
        dg = diagnose_design(design, _rng(seed, "fit"), settings, phase=step)
        step(steps[-2])
        residual_after = _row_residual(table, design, dg)
        loc_after = localize(
            table, residual_after, rng=_rng(seed, "localize-after"), n_boot=LOCALIZE_BOOT
        )
        step(steps[-1])
        doc = _write(
            table,
            design,
            dg,
            loc_before,
            loc_after,
            out,
            sim_root,
            real_root,
            source,
            paired,
            seed,
            settings,
        )
        bar.update(1)
    if write_corrected_to is not None:
        write_corrected(
            pair, table, design, dg.final, Path(write_corrected_to), seed, sim_table=sim_table
        )
    return doc


def _step_bar(total: int, progress: bool) -> tuple[tqdm[Any], Callable[[str], None]]:
    """A progress bar over `total` named steps and the function that starts the next one
    (completing the one before)."""
    bar = tqdm(
        total=total,
        desc="diagnose",
        unit="step",
        disable=not progress,
        bar_format="{desc} (step {n_fmt}/{total_fmt}, {elapsed})",
    )
    started: list[str] = []

    def step(name: str) -> None:
        if started:
            bar.update(1)
        started.append(name)
        bar.set_description_str(f"diagnose: {name}")

    return bar, step


def _write(
    table: BeamTable,
    design: Design,
    dg: Diagnosis,
    loc_before: Any,
    loc_after: Any,
    out: Path,
    sim_root: Path,
    real_root: Path,
    source: str,
    paired: bool,
    seed: int,
    settings: Settings,
) -> dict[str, Any]:
    """Figures, report.json and report.md under `out`; returns the report document."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figs = _figures(table, design, dg, loc_before, loc_after, out)
    context = {
        "sim_root": str(sim_root),
        "real_root": str(real_root),
        "source": source,
        "mode": "paired" if paired else "unpaired",
        "seed": seed,
        "rows": int(len(design)),
        "scans": len(table.scans),
        "sensor": dataclasses.asdict(table.sensor),
        "settings": dataclasses.asdict(settings),
        # Every threshold the run used, and a hash to compare reports by (config.py).
        "config": CONFIG.to_dict(),
        "config_sha256": CONFIG.sha256(),
        "localization_after": to_json(loc_after).get("statements", []),
        **_pairing(table, paired),
    }
    doc = build_report(dg, context, to_json(loc_before), figs)
    write_report(doc, out)
    return doc


def _pairing(table: BeamTable, paired: bool) -> dict[str, Any]:
    """How many beams returned in both trees, in one, or in the other (paired runs), and a
    warning when few returned in both: paired trees are the same scenes from the same
    poses, so most beams should."""
    if not paired:
        return {"warnings": []}
    both = int((table.ret_sim & table.ret_real).sum())
    counts = {
        "both": both,
        "real_only": int((table.ret_real & ~table.ret_sim).sum()),
        "sim_only": int((table.ret_sim & ~table.ret_real).sum()),
    }
    share = both / max(1, both + counts["real_only"] + counts["sim_only"])
    warnings = []
    if share < PAIRED_SHARE_WARN:
        warnings.append(
            f"only {share:.0%} of the beams returned in both trees: paired trees should be the "
            "same scenes rendered from the real scans' poses; if they are not, compare them "
            "unpaired (--unpaired)"
        )
    return {"pairing": {**counts, "share_both": round(share, 4)}, "warnings": warnings}


def _check_outside(folder: Path, option: str, *roots: Path) -> None:
    """DiagnoseError when `folder` is one of the compared trees or inside one: lads never
    writes into a dataset it reads."""
    where = Path(folder).resolve()
    for root in roots:
        tree = Path(root).resolve()
        if where == tree or tree in where.parents:
            raise DiagnoseError(
                f"{folder}: {option} is inside the compared tree {root}; lads never writes into "
                f"a dataset it reads. Choose a {option} folder outside both trees."
            )


def _check_fit_data(d: Design, sim_root: Path, real_root: Path) -> None:
    groups = len(np.unique(d.group))
    if len(d) < MIN_ROWS or groups < MIN_GROUPS:
        raise DiagnoseError(
            f"{sim_root} vs {real_root}: {len(d)} comparable beams in {groups} spatial groups; "
            f"at least {MIN_ROWS} beams in {MIN_GROUPS} groups are needed to fit and hold out "
            "effects. Add scans (or, unpaired, scans that cover the same classes and ranges)."
        )
    ret = d.returned.numpy()
    for name, values in (("real", d.y.numpy()[ret]), ("simulated", d.ln_sim.numpy())):
        if values.size and float(np.ptp(values)) == 0.0:
            raise DiagnoseError(
                f"{real_root if name == 'real' else sim_root}: every {name} intensity is the "
                "same value; there is no intensity variation to explain. Check that the tree "
                "holds the intensity column (not a constant placeholder)."
            )


def _row_residual(table: BeamTable, d: Design, dg: Diagnosis | None) -> np.ndarray:
    """(len(table),) residual ln(I_real + h) minus the prediction (NaN where undefined)."""
    out = np.full(len(table), np.nan)
    pred = d.ln_sim.numpy() if dg is None else dg.final.predictions(d)[0]
    ret = d.fits_intensity
    out[d.rows[ret]] = d.y.numpy()[ret] - pred[ret]
    return out


def _figures(
    table: BeamTable, d: Design, dg: Diagnosis, before: Any, after: Any, out: Path
) -> list[str]:
    written = [
        figures.residual_panels(before, after, out / "residuals.png"),
        figures.heatmaps(before, out / "heatmaps.png"),
        figures.selection_trace(
            [s.to_json() for s in dg.selection.trace], out / "selection_trace.png"
        ),
    ]
    if d.paired:
        prob = np.full(len(table), np.nan)
        prob[d.rows] = dg.final.predictions(d)[2]
        written.append(figures.return_rate(table, prob, out / "return_rate.png"))
    if "by_range" in dg.noise_model.get("point_noise", {}):
        written.append(figures.point_noise(dg.noise_model["point_noise"], out / "point_noise.png"))
    samples = {
        f"{r.effect.label}.{k}": v for r in dg.effects for k, v in r.samples.items() if v.size
    }
    if samples:
        written.append(figures.bootstrap_histograms(samples, out / "bootstrap.png"))
    for r in dg.effects:
        if r.effect.info.id == "C4":
            gains = np.asarray(r.params["ln_gain_by_ring"])
            ci = r.ci95.get("ln_gain_by_ring") or [[np.nan, np.nan]] * len(gains)
            lo = np.array([c[0] for c in ci])
            hi = np.array([c[1] for c in ci])
            written.append(figures.ring_gains(gains, lo, hi, out / "ring_gains.png"))
    return [Path(p).name for p in written]
