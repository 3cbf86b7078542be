"""Group-bootstrap resamples of a diagnosis: fit weights over resampled groups (scans first,
then the groups within them) and the parameters refitted on each, for the intervals and the
stability resamples of `lads.diagnose.verdict.analysis`."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from lads.diagnose.fit.design import Design
from lads.diagnose.fit.model import Fit, fit
from lads.diagnose.fit.parallel import map_fits, one_thread
from lads.diagnose.selection.grouping import fit_weights


def group_multiplicity(
    d: Design, rows: npt.NDArray[np.int64], rng: np.random.Generator, by_scan: bool = False
) -> npt.NDArray[np.float64]:
    """(N,) bootstrap counts: the groups of `rows` resampled with replacement; `by_scan`:
    in two stages, the scans with replacement, then each drawn scan's groups."""
    groups, first = np.unique(d.group[rows], return_index=True)
    if by_scan:
        draw = _two_stage_draw(groups, d.scan.numpy()[rows[first]], rng)
    else:
        draw = rng.choice(groups, size=len(groups), replace=True)
    uniq, counts = np.unique(draw, return_counts=True)
    mult = np.zeros(len(d))
    pos = np.searchsorted(uniq, d.group[rows])
    pos = np.clip(pos, 0, len(uniq) - 1)
    hit = uniq[pos] == d.group[rows]
    mult[rows[hit]] = counts[pos[hit]]
    return mult


def _two_stage_draw(
    groups: npt.NDArray[np.int64], scan_of: npt.NDArray[np.int64], rng: np.random.Generator
) -> npt.NDArray[np.int64]:
    """Groups drawn scan first (`scan_of`: each group's scan), then within each drawn scan."""
    scans = np.unique(scan_of)
    parts = []
    for s in rng.choice(scans, size=len(scans), replace=True):
        own = groups[scan_of == s]
        parts.append(rng.choice(own, size=len(own), replace=True))
    return np.concatenate(parts)


def bootstrap_weights(
    d: Design,
    rows: npt.NDArray[np.int64],
    cap: int,
    n: int,
    rng: np.random.Generator,
    by_scan: bool = False,
) -> list[npt.NDArray[np.float64]]:
    """`n` fit-weight vectors over group-bootstrap resamples of `rows` (drawn in order);
    `by_scan`: scans first, then groups within them (`group_multiplicity`)."""
    out = []
    for _ in range(n):
        mult = group_multiplicity(d, rows, rng, by_scan)
        out.append(fit_weights(len(d), rows, cap, rng, mult))
    return out


def _refits(
    d: Design, ws: list[npt.NDArray[np.float64]], _extra: Any, final: Fit
) -> list[npt.NDArray[np.float64]]:
    with one_thread():
        return [fit(final.model, d, w, final.theta, max_iter=100).theta for w in ws]


def bootstrap_params(
    final: Fit,
    d: Design,
    rows: npt.NDArray[np.int64],
    cap: int,
    n_boot: int,
    rng: np.random.Generator,
    jobs: int = 1,
) -> npt.NDArray[np.float64]:
    """(n_boot, P) parameter vectors refitted on group-bootstrap resamples (warm start)."""
    # Scans first: what varies between scans (their gain, their AGC level, their own
    # objects) is fixed in a tile bootstrap, whose intervals then missed a scan-level AGC's
    # beta and an attenuation by 2-3 bootstrap SDs. With one scan this is the tile bootstrap.
    ws = bootstrap_weights(d, rows, cap, n_boot, rng, by_scan=True)
    out = map_fits(_refits, d, ws, np.zeros(0, dtype=np.int64), jobs, final)
    return np.array(out) if out else np.zeros((0, final.model.size))
