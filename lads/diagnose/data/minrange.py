"""Drop returns nearer than the sensor's minimum range before they enter a beam table.

Nearer than the profile's `min_range_m` (R1: transmitter and receiver fields of view do not
overlap yet) a return is the ego vehicle, the mounting or a reflection inside the housing,
not the scene: nuScenes keeps such returns (about 23 % of a HDL-32E keyframe lies within
1 m), and a simulator usually has none, so they would show up as spurious extra or
mismatched beams.

Paired scans are filtered as pairs: the association runs on the whole clouds, and a point
nearer than the minimum range takes its partner out of the other tree with it. Filtering
each tree on its own would turn a pair straddling the cut (sim 0.98 m, real 1.02 m) into a
dropped or an extra beam that neither recording shows.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from lads.diagnose.data.trees import Scan


def beyond_min_range(scan: Scan, min_range_m: float) -> Scan:
    """`scan` without its points nearer than `min_range_m` (m); file rows are kept."""
    return scan.take(np.flatnonzero(scan.range_m() >= min_range_m))


def pairs_beyond_min_range(
    sim: Scan, real: Scan, partner: npt.NDArray[np.int64], min_range_m: float
) -> tuple[Scan, Scan, npt.NDArray[np.int64]]:
    """Both scans without the points nearer than `min_range_m` (m), and without their partners.

    Args:
        sim, real: one scan of each tree, N and M points.
        partner: (N,) int64 index into `real` of each simulated point's partner, -1 if none
            (`lads.diagnose.data.pairing.pair_points`).
        min_range_m: minimum range, m.

    Returns:
        (sim kept, real kept, partner of each kept simulated point as an index into the kept
        real points, -1 if none). A kept point's partner is always kept, so the association
        stays one-to-one.
    """
    near_sim = sim.range_m() < min_range_m
    near_real = real.range_m() < min_range_m
    paired = partner >= 0
    drop_sim = near_sim.copy()
    drop_sim[paired] |= near_real[partner[paired]]
    drop_real = near_real.copy()
    drop_real[partner[paired & near_sim]] = True
    keep_sim, keep_real = np.flatnonzero(~drop_sim), np.flatnonzero(~drop_real)
    real_position = np.full(len(real), -1, dtype=np.int64)
    real_position[keep_real] = np.arange(keep_real.size)
    kept = partner[keep_sim]
    kept_partner = np.full(keep_sim.size, -1, dtype=np.int64)
    has = kept >= 0
    kept_partner[has] = real_position[kept[has]]
    return sim.take(keep_sim), real.take(keep_real), kept_partner
