"""The source's field of view in a sensor transfer (docs/transfer.md §2).

A target ring above or below the source's vertical field of view sees only what neighbouring
scans lend, recorded at other times. Where the scan being transferred shows a thing that moves
at the edge of its view (a car beside the vehicle, cut off below by the source's lowest ring),
the thing may go on beyond that edge, and what the neighbours saw behind it when it was not
there is not what the target would see: those beams are left empty (nothing known) instead of
showing the road through the car.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def covered_rings(
    source_el_deg: npt.ArrayLike, target_el_deg: npt.ArrayLike
) -> npt.NDArray[np.bool_]:
    """(target channels,) True where the target's elevation lies within the source's vertical
    field of view, widened by half its edge ring gaps: the rings a transfer can fill (between
    source rings too), the others have nothing the source saw."""
    src = np.asarray(source_el_deg, dtype=np.float64)
    tgt = np.asarray(target_el_deg, dtype=np.float64)
    low = src[0] - 0.5 * (src[1] - src[0])
    high = src[-1] + 0.5 * (src[-1] - src[-2])
    return (tgt >= low) & (tgt <= high)


def hidden_beyond_view(
    range_m: npt.NDArray[np.float64],
    moving_here: npt.NDArray[np.bool_],
    lent: npt.NDArray[np.bool_],
    covered: npt.NDArray[np.bool_],
) -> npt.NDArray[np.bool_]:
    """(H, W) beams outside the source's view that show a neighbour's surface behind a moving
    thing of the transferred scan.

    Args:
        range_m: (H, W) range of each beam's hit, m (inf without one); rows are the target's
            channels, lowest first.
        moving_here: (H, W) the beam hit a surfel of the transferred scan itself that is of a
            class of things that move.
        lent: (H, W) the beam hit a surfel lent by a neighbouring scan.
        covered: (H,) the rings inside the source's view (`covered_rings`).

    Returns:
        (H, W) bool: beams beyond the first or last covered ring, lent, and farther than a
        moving thing that the edge ring shows in the same column or the next one on either
        side (the edge sampling has gaps of a column).
    """
    hidden = np.zeros(range_m.shape, dtype=bool)
    rows = np.flatnonzero(covered)
    if rows.size == 0:
        return hidden
    for edge, beyond in ((rows[0], slice(0, rows[0])), (rows[-1], slice(rows[-1] + 1, None))):
        if range_m[beyond].size == 0 or not moving_here[edge].any():
            continue
        at_edge = np.where(moving_here[edge], range_m[edge], np.inf)
        nearest = np.minimum(at_edge, np.minimum(np.roll(at_edge, 1), np.roll(at_edge, -1)))
        hidden[beyond] = lent[beyond] & (range_m[beyond] > nearest[None, :])
    return hidden
