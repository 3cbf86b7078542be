"""Distance of each return to the nearest depth edge along its ring, in beams (C8's feature).

Distances run along the ring only, in azimuth steps of the sensor (one step = one firing):
rings lie 2-3 steps apart, and on a continuous surface at a grazing angle (the ground beyond
~15 m) neighbouring rings differ by more than 1 m in range, so vertical "jumps" would put a
third of a KITTI scan at distance 0 from an edge that is not there.

The distance is measured on the returns themselves, in azimuth order, not on a range image:
a 2048-column image of an HDL-64E scan gives ~20 % of the returns no pixel of their own
(the sensor fires ~2000 times a turn, not on the image's grid), a return that shares a
pixel inherits its neighbour's distance, and pixel units differ from firings by the
ratio of the two. Both blurred the exponential decay C8 is fitted to.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from lads.diagnose.config import CONFIG

EDGE_JUMP_M = CONFIG.table.edge_jump_m
# More missing returns than this many median spacings between two returns of a ring is a
# depth edge (no return: sky, beyond range, a black or mirror-like surface). On a scan
# thinned at random to a third, 4 spacings is exceeded between ~4 % of neighbours.
EDGE_GAP_SPACINGS = CONFIG.table.edge_gap_spacings
# The azimuth step is the commonest gap between neighbouring returns: on a scan thinned at
# random the gaps are whole numbers of steps and one step is still the commonest (the
# lowest quantiles are no guide: many gaps of a KITTI ring are half a step). Mode
# on log-spaced bins of STEP_BIN_LN wide, then the median of the gaps within STEP_BAND_LN.
STEP_BIN_LN = CONFIG.table.step_bin_ln
STEP_BAND_LN = CONFIG.table.step_band_ln
MIN_STEP_GAPS = CONFIG.table.min_step_gaps


def azimuth_step_rad(azimuth_rad: npt.ArrayLike, ring: npt.ArrayLike) -> float:
    """The sensor's azimuth step (rad) seen in one scan: the median of its commonest gaps.

    Args:
        azimuth_rad: (N,) azimuth of each return.
        ring: (N,) ring (laser) of each return.

    Returns:
        The step in rad; 2 pi / N when the scan has fewer than MIN_STEP_GAPS gaps.
    """
    order, ring_sorted = _ring_order(azimuth_rad, ring)
    gap, _, _, count = _ring_gaps(ring_sorted, np.asarray(azimuth_rad, np.float64)[order])
    return _step_of_gaps(gap, count)


def _step_of_gaps(gap: npt.NDArray[np.float64], count: npt.NDArray[np.int64]) -> float:
    """`azimuth_step_rad` from the gaps `_ring_gaps` found (and their rings' sizes)."""
    n = gap.size
    gap = gap[(count >= 3) & (gap > 0)]
    if gap.size < MIN_STEP_GAPS:
        return 2.0 * math.pi / max(n, 1)
    ln_gap = np.log(gap)
    bins = np.arange(ln_gap.min(), ln_gap.max() + 2 * STEP_BIN_LN, STEP_BIN_LN)
    counts, edges = np.histogram(ln_gap, bins=bins)
    mode = edges[int(np.argmax(counts))] + 0.5 * STEP_BIN_LN
    return float(np.exp(np.median(ln_gap[np.abs(ln_gap - mode) <= STEP_BAND_LN])))


def edge_distance(
    xyz: npt.ArrayLike,
    ring: npt.ArrayLike,
    *,
    cap: float,
    step_rad: float | None = None,
    jump_m: float = EDGE_JUMP_M,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """(N,) float32 distance in beams from each return to the nearest depth edge of its ring,
    and (N,) float32 the width in beams of the span that edge can lie in.

    Along a ring, two consecutive returns meet at an edge when their ranges differ by more
    than `jump_m`, or when more than EDGE_GAP_SPACINGS times the ring's median spacing of
    returns is missing between them (a beam that half-hit an object and half went to the
    sky is a depth edge too). A range jump's edge sits midway between the two returns, a
    missing run's half a spacing beyond each bordering return; a return's distance is
    counted from the edge minus half a beam, so both returns of an adjacent pair are at 0,
    as in a full scan. On a thinned scan, where the true edge is somewhere in the gap, the
    midpoint is the unbiased guess (with edges at the returns themselves, every mixed pixel
    of a thinned scan looked like e = 0, and the fitted e0 hit its lower bound). The span
    says how far off that guess can be: a jump between returns g steps apart lies anywhere
    in g - 1 steps, so the true distance is uniform on distance +- span / 2 (clipped at 0);
    on a full scan the span is ~0.

    Args:
        xyz: (N, 3) coordinates in m, sensor at the origin.
        ring: (N,) ring of each return.
        cap: distances are clipped to [0, cap] beams; rings without an edge get `cap`.
        step_rad: the azimuth step; default `azimuth_step_rad` of this scan.
        jump_m: range difference of a depth edge, m.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    out = np.full(n, cap, dtype=np.float32)
    span_out = np.zeros(n, dtype=np.float32)
    if n == 0:
        return out, span_out
    azimuth = np.arctan2(xyz[:, 1], xyz[:, 0])
    order, ring_sorted = _ring_order(azimuth, ring)
    gap_rad, nxt, start, count = _ring_gaps(ring_sorted, azimuth[order])
    step = _step_of_gaps(gap_rad, count) if step_rad is None else float(step_rad)
    range_m = np.linalg.norm(xyz, axis=1)[order]
    gap = gap_rad / step
    spacing = _ring_spacing(gap, start)
    missing = (count >= 3) & (gap > EDGE_GAP_SPACINGS * spacing)
    jump = (np.abs(range_m[nxt] - range_m) > jump_m) & ~missing
    # Each ring gets its own stretch of one axis, far enough apart that no ring's edge is
    # ever within `cap` of another ring's return; copies one period either side wrap 0/2 pi.
    period = 2.0 * math.pi / step
    stride = 4.0 * period + 4.0 * cap
    pos = azimuth[order] / step + _dense_rank(ring_sorted) * stride
    edges, width = _edges_and_widths(pos, gap, spacing, jump, missing)
    if edges.size == 0:
        return out, span_out
    dist, span = _nearest_edge(edges, width, pos, period, cap)
    out[order] = dist.astype(np.float32)
    span_out[order] = span.astype(np.float32)
    return out, span_out


def _edges_and_widths(
    pos: npt.NDArray[np.float64],
    gap: npt.NDArray[np.float64],
    spacing: npt.NDArray[np.float64],
    jump: npt.NDArray[np.bool_],
    missing: npt.NDArray[np.bool_],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(E,) edge positions and (E,) widths of their spans, in azimuth steps along the rings."""
    # A range jump's edge is its midpoint; a missing run's, half a spacing inside each end.
    edges = np.concatenate(
        [
            pos[jump] + 0.5 * gap[jump],
            pos[missing] + 0.5 * spacing[missing],
            pos[missing] + gap[missing] - 0.5 * spacing[missing],
        ]
    )
    width = np.maximum(np.concatenate([gap[jump], spacing[missing], spacing[missing]]) - 1.0, 0.0)
    return edges, width


def _ring_spacing(
    gap: npt.NDArray[np.float64], start: npt.NDArray[np.int64]
) -> npt.NDArray[np.float64]:
    """(N,) median spacing of returns (in azimuth steps, >= 1) of each return's ring; 1 for
    rings of fewer than 3 returns. `gap`: steps to the next return in ring order; `start`:
    where each return's ring starts in that order."""
    spacing = np.ones(gap.size)
    for s, c in zip(*np.unique(start, return_counts=True), strict=True):
        if c >= 3:  # each ring's returns are one contiguous run of the sorted order
            spacing[s : s + c] = max(float(np.median(gap[s : s + c])), 1.0)
    return spacing


def _nearest_edge(
    edges: npt.NDArray[np.float64],
    width: npt.NDArray[np.float64],
    pos: npt.NDArray[np.float64],
    period: float,
    cap: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Per position `pos` (in azimuth steps along the rings' axis), the distance in beams
    to the nearest edge, clipped to [0, cap], and that edge's span (0 beyond `cap`); the
    edges are copied one `period` either side so 0 and 2 pi meet."""
    edges = np.concatenate([edges - period, edges, edges + period])
    width = np.tile(width, 3)
    by_pos = np.argsort(edges, kind="stable")
    edges, width = edges[by_pos], width[by_pos]
    right = np.minimum(np.searchsorted(edges, pos), edges.size - 1)
    left = np.maximum(right - 1, 0)
    take_right = np.abs(edges[right] - pos) < np.abs(pos - edges[left])
    nearest = np.where(take_right, right, left)
    dist = np.clip(np.abs(edges[nearest] - pos) - 0.5, 0.0, cap)
    return dist, np.where(dist < cap, width[nearest], 0.0)


def _ring_order(
    azimuth_rad: npt.ArrayLike, ring: npt.ArrayLike
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    ring = np.asarray(ring, dtype=np.int64)
    order = np.lexsort((np.asarray(azimuth_rad), ring))
    return order, ring[order]


def _ring_gaps(
    ring_sorted: npt.NDArray[np.int64], az: npt.NDArray[np.float64]
) -> tuple[
    npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]
]:
    """Per return in ring-then-azimuth order (`az` in that order): the azimuth gap to the
    next return of its ring (wrapping), that return's index, where its ring starts and the
    ring's size."""
    n = ring_sorted.size
    new = np.r_[True, ring_sorted[1:] != ring_sorted[:-1]] if n else np.zeros(0, bool)
    starts = np.flatnonzero(new)
    sizes = np.diff(np.r_[starts, n])
    start = np.repeat(starts, sizes)
    count = np.repeat(sizes, sizes)
    nxt = np.arange(1, n + 1)
    last = np.r_[new[1:], True] if n else np.zeros(0, bool)
    nxt[last] = start[last]  # the ring's last return pairs with its first (wrap)
    gap = np.mod(az[nxt] - az, 2.0 * math.pi) if n else np.zeros(0)
    gap[count == 1] = 2.0 * math.pi  # a ring with a single return
    return gap, nxt, start, count


def _dense_rank(values: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    return np.unique(values, return_inverse=True)[1].ravel()
