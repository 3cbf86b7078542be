"""`--write-corrected`: the simulation tree with the fitted effects applied, same format.

Every file of the simulated tree is copied; each scan's points get the fitted prediction of
the real intensity (exp(mu) - h, rounded to the encoding's step and clipped), and beams the
fitted dropout says are lost are removed together with their label rows, so the corrected
tree can be compared with the real one by any tool. Dropout draws come from a generator
seeded by (seed, relpath), so the output does not depend on scan order.

Predicted are the fitted rows and the simulated returns the fit left out for being stored
at the encoding's maximum (`design.prediction_design`); unpaired, every simulated return
(the fitted rows are real beams of other scans). Points the analysis did not see (nearer
than the sensor's minimum range, zero range) are kept unchanged. A nuScenes tree with
devkit tables keeps every point (its lidarseg files are addressed by token and count), only
intensities change; so does every unpaired tree (no dropout is fitted without pairs).
"""

from __future__ import annotations

import hashlib
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from lads.diagnose.data.table import BeamTable, SensorInfo
from lads.diagnose.data.trees import TreePair
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.from_table import prediction_design, saturated_rows
from lads.diagnose.fit.model import Fit
from lads.errors import DiagnoseError
from lads.files import atomic_write


def write_corrected(
    pair: TreePair,
    table: BeamTable,
    design: Design,
    fit: Fit,
    out_root: Path,
    seed: int,
    sim_table: BeamTable | None = None,
) -> int:
    """Write the corrected simulation tree to `out_root`; returns the number of scans written.

    `table` is the table `design` was built from; unpaired, `sim_table` is the simulated
    tree's own table (required there).

    Raises:
        DiagnoseError: `out_root` is the simulated or real tree itself, or holds files
            that are not an earlier corrected tree's.
        ReaderError: a scan the source's reader refuses (the message names the file).
    """
    out_root = Path(out_root)
    for root in (pair.sim_root, pair.real_root):
        if out_root.resolve() == Path(root).resolve():
            raise DiagnoseError(
                f"--write-corrected {out_root}: that is an input tree; pick a new folder."
            )
    _clear_previous(out_root, Path(pair.sim_root))
    shutil.copytree(pair.sim_root, out_root)
    table, parts = _parts_to_predict(table, design, sim_table)
    predicted = [fit.predictions(part) for part in parts]
    mu = np.concatenate([m for m, _, _ in predicted])
    p = np.concatenate([q for _, _, q in predicted])
    intensity = np.exp(mu) - design.half_step
    # Without any dropout effect the constant return rate is the sensor's random loss, which
    # the simulation is not asked to reproduce: only fitted dropout mechanisms remove beams.
    has_dropout = design.paired and any(
        e.log_survival is not None or e.extra.get("threshold") for e in fit.model.effects
    )
    base_rate = 1.0 / (1.0 + np.exp(-fit.theta[4]))
    table_rows = np.concatenate([part.rows for part in parts])
    scan_of_row = table.scan[table_rows]
    sim_index = table.sim_index[table_rows]
    written = 0
    for s, relpath in enumerate(table.scans):
        sel = scan_of_row == s
        if not sel.any():
            continue
        _rewrite(
            pair,
            out_root,
            relpath,
            sim_index[sel],
            intensity[sel],
            (p[sel] / base_rate) if has_dropout else None,
            seed,
            table.sensor,
        )
        written += 1
    return written


def _parts_to_predict(
    table: BeamTable, design: Design, sim_table: BeamTable | None
) -> tuple[BeamTable, list[Design]]:
    """The table whose beams are rewritten and the designs to predict them from: paired,
    `design` and the saturated beams; unpaired, every simulated return of `sim_table`.

    Raises:
        DiagnoseError: unpaired without `sim_table`.
    """
    if design.paired:
        parts = [design]
        saturated = saturated_rows(table)
        if saturated.size:
            parts.append(prediction_design(table, saturated, design))
        return table, parts
    if sim_table is None:
        raise DiagnoseError(
            "an unpaired corrected tree needs the simulated tree's table "
            "(write_corrected(..., sim_table=...))."
        )
    rows = np.flatnonzero(sim_table.ret_sim & np.isfinite(sim_table.i_sim))
    return sim_table, [prediction_design(sim_table, rows, design)]


def _clear_previous(out_root: Path, sim_root: Path) -> None:
    """Remove `out_root` only if it is empty or an earlier corrected tree of `sim_root` (the
    same relative file paths: a corrected tree is a copy with scans rewritten in place).

    Raises:
        DiagnoseError: `out_root` holds anything else; nothing is removed then.
    """
    if not out_root.exists():
        return
    if not out_root.is_dir():
        raise DiagnoseError(
            f"--write-corrected {out_root}: exists and is not a folder; pick a new folder."
        )
    theirs = {p.relative_to(out_root).as_posix() for p in out_root.rglob("*")}
    ours = {p.relative_to(sim_root).as_posix() for p in sim_root.rglob("*")}
    if theirs and theirs != ours:
        extra = sorted(theirs - ours)[:3] or sorted(ours - theirs)[:3]
        raise DiagnoseError(
            f"--write-corrected {out_root}: the folder exists and is not an earlier corrected "
            f"tree of {sim_root} (e.g. {extra} differ); lads only replaces its own output. "
            "Pick a new folder or remove this one yourself."
        )
    shutil.rmtree(out_root)


def _rewrite(
    pair: TreePair,
    out_root: Path,
    relpath: str,
    rows: npt.NDArray[np.int64],
    intensity: npt.NDArray[np.float64],
    p_keep: npt.NDArray[np.float64] | None,
    seed: int,
    sensor: SensorInfo,
) -> None:
    """Rewrite one scan of the corrected tree: the predicted intensities of `rows` and, with a
    fitted dropout, only the beams that survive it (their label rows with them). Files go
    through the tree's reader (`encode`)."""
    frame = pair.read_frame("sim", relpath)
    points, columns = frame.points.copy(), frame.columns
    step, top = sensor.step, sensor.max_value
    value = np.clip(np.round(intensity / step) * step, 0.0, top).astype(np.float32)
    points[rows, columns.index("intensity")] = value
    keep = np.ones(len(points), dtype=bool)
    devkit_tables = any(Path(pair.sim_root).glob("v1.0-*"))
    if p_keep is not None and not devkit_tables:
        digest = hashlib.sha256(f"{seed}/{relpath}/corrected".encode()).digest()
        rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        keep[rows] = rng.random(len(rows)) < np.clip(p_keep, 0.0, 1.0)
    kept = replace(
        frame,
        points=points[keep],
        labels=None if frame.labels is None else frame.labels[keep],
        extra_labels={role: values[keep] for role, values in frame.extra_labels.items()},
    )
    reader = pair.reader("sim")
    # The scan always changes; label files only where beams were dropped (else the copy stands).
    for encoded in reader.encode(kept):
        if encoded.role == "scan" or not keep.all():
            atomic_write(out_root / encoded.relpath, encoded.payload)
