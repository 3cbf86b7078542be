"""Pass 2 of the cast (docs/transfer.md §2): each beam's depth, owner, reflectivity and
incidence from the hit records of pass 1 (`cast._record_hits`)."""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
# The depth window of a grazing beam widens as 1 / cos(incidence), down to this cosine: the
# disks of one surface spread along such a beam by their normal errors over cos.
MIN_TOL_COS = 0.1


@numba.njit(cache=True, nogil=True)
def blend_hits(
    best: F64,
    best_cos: F64,
    floor: F64,
    hit_pix: npt.NDArray[np.int64],
    hit_t: F64,
    hit_cos: F64,
    hit_w: F64,
    hit_i: npt.NDArray[np.int64],
    hit_seen: F64,
    hit_trust: F64,
    depth_tol_m: float,
    depth_tol_share: float,
) -> tuple[F64, npt.NDArray[np.int64], F64, F64]:
    """Pass 2: (H, W) blended distance (inf: none), owner (-1: none), reflectivity (0: none)
    and the |cos| of incidence on the owner (0: none).

    Hits nearer than the beam's `floor` (free space of the centre scan, `lads.transfer.carve`;
    0: none) take no part. Every hit within max(depth_tol_m, depth_tol_share t0) /
    max(cos, MIN_TOL_COS) behind the
    beam's nearest (cos: the incidence there) votes with its weight: the surfels of one
    surface then vote for its depth instead of the nearest of them winning (the nearest of
    many noisy surfels lies in front of the surface). The owner is the hit nearest its
    surfel's centre."""
    rows, columns = best.shape
    owner = np.full((rows, columns), -1, dtype=np.int64)
    owner_cos = np.zeros((rows, columns))
    sum_w = np.zeros((rows, columns))
    sum_wt = np.zeros((rows, columns))
    sum_wn = np.zeros((rows, columns))
    sum_wd = np.zeros((rows, columns))
    best_w = np.full((rows, columns), -1.0)
    for h in range(hit_pix.shape[0]):
        k = hit_pix[h] // columns
        j = hit_pix[h] - k * columns
        t = hit_t[h]
        tol = max(depth_tol_m, depth_tol_share * best[k, j])
        if t < floor[k, j] or t > best[k, j] + tol / max(best_cos[k, j], MIN_TOL_COS):
            continue
        i = hit_i[h]
        wt = hit_w[h]
        sum_w[k, j] += wt
        sum_wt[k, j] += wt * t
        sum_wn[k, j] += wt * hit_trust[h] * hit_seen[h]
        sum_wd[k, j] += wt * hit_trust[h]
        if wt > best_w[k, j] or (wt == best_w[k, j] and i < owner[k, j]):
            best_w[k, j] = wt
            owner[k, j] = i
            owner_cos[k, j] = hit_cos[h]
    out = np.full((rows, columns), np.inf)
    blended = np.zeros((rows, columns))
    for k in range(rows):
        for j in range(columns):
            if sum_w[k, j] > 0.0:
                out[k, j] = sum_wt[k, j] / sum_w[k, j]
                if sum_wd[k, j] > 0.0:
                    blended[k, j] = sum_wn[k, j] / sum_wd[k, j]
    return out, owner, blended, owner_cos
