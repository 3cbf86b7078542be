"""One-to-one nearest-neighbour association of simulated and real returns (paired mode).

A simulated point that loses its nearest real point to a nearer simulated one goes on to its
next nearest unclaimed one: with a strict "loser is unpaired" rule, exact duplicate rows
(WADS: 42 % of rows) and clusters of coincident ego returns (nuScenes) would leave all but
one copy unpaired, showing up as spurious dropped and extra beams.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from lads.diagnose.config import CONFIG

PAIR_CANDIDATES = CONFIG.table.pair_candidates
_MAX_PAIR_PASSES = 64


def pair_points(
    sim_xyz: npt.NDArray[np.float64],
    real_xyz: npt.NDArray[np.float64],
    max_distance_m: float,
    *,
    candidates: int = PAIR_CANDIDATES,
) -> npt.NDArray[np.int64]:
    """One-to-one association of simulated to real points by nearest neighbour.

    Each simulated point claims its nearest unclaimed real point within `max_distance_m`;
    when several claim one real point the nearest wins (ties: the lower simulated index),
    and the others go on to their next nearest unclaimed real point within the distance.

    Args:
        sim_xyz: (N, 3) float64 m. real_xyz: (M, 3) float64 m.
        max_distance_m: largest pair distance, m.
        candidates: real neighbours fetched per query (more are fetched in later passes).

    Returns:
        (N,) int64 index into real_xyz of each simulated point's partner, -1 if none.
    """
    partner = np.full(len(sim_xyz), -1, dtype=np.int64)
    pending = np.arange(len(sim_xyz))
    free_real = np.arange(len(real_xyz))
    # A pass ends when every pending point has matched or used up its fetched candidates;
    # clusters of more than `candidates` coincident points (nuScenes ego returns, WADS
    # duplicates) need further passes over the real points still unclaimed.
    for _ in range(_MAX_PAIR_PASSES):
        if pending.size == 0 or free_real.size == 0:
            break
        got, exhausted = _pair_pass(
            sim_xyz[pending], real_xyz[free_real], max_distance_m, candidates
        )
        matched = got >= 0
        if not matched.any():
            break
        partner[pending[matched]] = free_real[got[matched]]
        still_free = np.ones(free_real.size, dtype=bool)
        still_free[got[matched]] = False
        free_real = free_real[still_free]
        pending = pending[~matched & exhausted]
    return partner


def _pair_pass(
    sim_xyz: npt.NDArray[np.float64], real_xyz: npt.NDArray[np.float64], max_d: float, k: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """Greedy rounds over k fetched candidates: (partner or -1, all k were within max_d)."""
    n_sim, n_real = len(sim_xyz), len(real_xyz)
    k = min(k, n_real)
    dist, idx = cKDTree(real_xyz).query(sim_xyz, k=k, distance_upper_bound=max_d)
    dist, idx = dist.reshape(n_sim, k), idx.reshape(n_sim, k)
    partner = np.full(n_sim, -1, dtype=np.int64)
    claimed = np.zeros(n_real + 1, dtype=bool)
    claimed[n_real] = True  # cKDTree's index for "no neighbour within the distance"
    active = np.flatnonzero(idx[:, 0] < n_real)
    for _ in range(k):  # each lost round uses up at least one candidate of every loser
        free = ~claimed[idx[active]]
        has = free.any(axis=1)
        active, free = active[has], free[has]
        if active.size == 0:
            break
        col = free.argmax(axis=1)
        cand, d = idx[active, col], dist[active, col]
        order = np.lexsort((active, d, cand))
        first = np.ones(order.size, dtype=bool)
        first[1:] = cand[order[1:]] != cand[order[:-1]]
        win = order[first]
        partner[active[win]] = cand[win]
        claimed[cand[win]] = True
        lost = np.ones(active.size, dtype=bool)
        lost[win] = False
        active = active[lost]
    return partner, idx[:, k - 1] < n_real
