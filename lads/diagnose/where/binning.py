"""The binned features of the localization (docs/diagnose.md §5.2).

Each `Feature` turns a beam table into a `Binning`: a bin per row (-1 where the feature does
not apply), labels with units, bin centres, and for ordered features the per-row value the
trend test regresses on (`lads.diagnose.where.binstats`). `FEATURES` lists them in report order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.diagnose.config import CONFIG
from lads.diagnose.data.table import EDGE_CAP_BEAMS, BeamTable

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Binning:
    """One feature's bins on one table.

    Attributes:
        index: (N,) int64 bin of every row; -1 = the row has no value of this feature.
        labels: (K,) bin labels, with units.
        centres: (K,) bin centres in the feature's unit (bin position if categorical).
        value: (N,) the trend variable of an ordered feature (its `unit`), else None.
    """

    index: I64
    labels: tuple[str, ...]
    centres: F64
    value: F64 | None


@dataclass(frozen=True, slots=True)
class Feature:
    """A binned feature: `bin(table)` gives its Binning, or None when it does not apply."""

    name: str
    title: str
    unit: str  # unit of the trend slope ("per m"); "" for categorical features
    ordered: bool
    bin: Callable[[BeamTable], Binning | None]


RANGE_EDGES_M = CONFIG.localize.range_edges_m
COS_BINS = CONFIG.localize.cos_bins
AZIMUTH_SECTOR_DEG = CONFIG.localize.azimuth_sector_deg
EDGE_EDGES_BEAMS = CONFIG.localize.edge_edges_beams
EDGE_LABELS = ("0 beams", "1 beam", "2 beams", "3-4 beams", "5-9 beams", "10+ beams")


def _edges_bin(values: F64, edges: F64, ok: npt.NDArray[np.bool_]) -> I64:
    """Bin by interior edges; values beyond the outer edges go to the end bins."""
    idx = np.clip(np.searchsorted(edges[1:-1], values, side="right"), 0, edges.size - 2)
    return np.where(ok & np.isfinite(values), idx, -1).astype(np.int64)


def _bin_range(t: BeamTable) -> Binning:
    edges = np.asarray(RANGE_EDGES_M)
    r = t.range_m.astype(np.float64)
    labels = tuple(f"{a:g}-{b:g} m" for a, b in zip(edges[:-1], edges[1:], strict=True))
    return Binning(
        _edges_bin(r, edges, np.ones(r.size, bool)),
        labels,
        np.sqrt(edges[:-1] * edges[1:]),
        np.clip(r, edges[0], edges[-1]),
    )


def _bin_cos(t: BeamTable) -> Binning:
    edges = np.linspace(0.0, 1.0, COS_BINS + 1)
    c = t.cos_incidence.astype(np.float64)
    labels = tuple(f"cos {a:.1f}-{b:.1f}" for a, b in zip(edges[:-1], edges[1:], strict=True))
    return Binning(_edges_bin(c, edges, t.normal_ok), labels, 0.5 * (edges[:-1] + edges[1:]), c)


def _categorical(
    values: npt.NDArray[Any], ok: npt.NDArray[np.bool_], names: Callable[[int], str]
) -> Binning:
    present = np.unique(values[ok])
    idx = np.where(ok, np.searchsorted(present, values), -1).astype(np.int64)
    return Binning(
        idx, tuple(names(int(v)) for v in present), np.arange(present.size, dtype=np.float64), None
    )


def _bin_class(t: BeamTable) -> Binning | None:
    known = t.class_id >= 0
    if not known.any():
        return None
    return _categorical(t.class_id, known, lambda c: t.class_names.get(c, f"class {c}"))


def _bin_ring(t: BeamTable) -> Binning:
    return _categorical(t.ring, np.ones(len(t), bool), lambda k: f"ring {k}")


def _bin_azimuth(t: BeamTable) -> Binning:
    n = int(round(360.0 / AZIMUTH_SECTOR_DEG))
    az = np.mod(t.azimuth_deg.astype(np.float64), 360.0)
    idx = np.clip(np.floor(az / AZIMUTH_SECTOR_DEG), 0, n - 1)
    idx = np.where(np.isfinite(az), idx, -1).astype(np.int64)
    labels = tuple(
        f"{i * AZIMUTH_SECTOR_DEG:g}-{(i + 1) * AZIMUTH_SECTOR_DEG:g} deg" for i in range(n)
    )
    return Binning(idx, labels, (np.arange(n) + 0.5) * AZIMUTH_SECTOR_DEG, None)


def _bin_i_sim(t: BeamTable) -> Binning | None:
    v = t.i_sim.astype(np.float64)
    ok = t.ret_sim & np.isfinite(v)
    if not ok.any():
        return None
    edges = np.unique(np.quantile(v[ok], np.linspace(0.0, 1.0, 11)))
    if edges.size < 2:
        edges = np.array([edges[0], edges[0]])
    labels = tuple(f"I_sim {a:.3g}-{b:.3g}" for a, b in zip(edges[:-1], edges[1:], strict=True))
    return Binning(_edges_bin(v, edges, ok), labels, 0.5 * (edges[:-1] + edges[1:]), v)


def _bin_edge(t: BeamTable) -> Binning:
    e = np.minimum(t.edge_beams.astype(np.float64), EDGE_CAP_BEAMS)
    edges = np.asarray(EDGE_EDGES_BEAMS)
    centres = np.array([0.0, 1.0, 2.0, 3.5, 7.0, EDGE_CAP_BEAMS])
    return Binning(_edges_bin(e, edges, np.ones(e.size, bool)), EDGE_LABELS, centres, e)


def _bin_ground(t: BeamTable) -> Binning:
    return Binning(
        t.is_ground.astype(np.int64), ("non-ground", "ground"), np.array([0.0, 1.0]), None
    )


def _bin_scan(t: BeamTable) -> Binning:
    k = max(len(t.scans), int(t.scan.max(initial=-1)) + 1)
    labels = tuple(t.scans[i] if i < len(t.scans) else f"scan {i}" for i in range(k))
    return Binning(t.scan.astype(np.int64), labels, np.arange(k, dtype=np.float64), None)


FEATURES: tuple[Feature, ...] = (
    Feature("range", "range", "m", True, _bin_range),
    Feature("cos_incidence", "cos(incidence)", "unit of cos(theta)", True, _bin_cos),
    Feature("class", "class", "", False, _bin_class),
    Feature("ring", "ring", "", False, _bin_ring),
    Feature("azimuth", "azimuth sector", "", False, _bin_azimuth),
    Feature("i_sim_decile", "I_sim decile", "stored unit of I_sim", True, _bin_i_sim),
    Feature("edge_distance", "distance to a range edge", "beam", True, _bin_edge),
    Feature("ground", "ground vs non-ground", "", False, _bin_ground),
    Feature("scan", "scan", "", False, _bin_scan),
)
"""The features of docs/diagnose.md §5.2, in report order."""
