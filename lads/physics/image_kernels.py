"""Compiled range-image loops (numba, cached on disk): ranges, pixel ownership, image normals.

The numpy forms of these loops sort every point and roll (H, W, 3) arrays a dozen times per
frame; they were most of the intensity stage's time. The loops below do the same arithmetic
in float64 in the same order, one pass each, so they return the values the numpy forms did.
The rules themselves are documented in `lads.physics.modalities` and `projection.organise`.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

# `_row_line_side`: how far beyond its two row neighbours' spacing a pixel may continue their
# line (the rings of a sensor meet flat ground ever farther apart with range).
ROW_LINE_REACH = 6.0


@numba.njit(cache=True, nogil=True)
def pixel_owners(
    pixel: npt.NDArray[np.int64], range_m: npt.NDArray[np.float64], n_pixels: int
) -> npt.NDArray[np.int64]:
    """(n_pixels,) index of the nearest point per pixel (-1 if none), ties to the lower index.

    Args:
        pixel: (N,) flat pixel of every point, in [0, n_pixels).
        range_m: (N,) range of every point in m.
        n_pixels: H * W.
    """
    owner = np.full(n_pixels, -1, dtype=np.int64)
    for i in range(pixel.shape[0]):
        p = pixel[i]
        j = owner[p]
        # Strictly nearer only: scanning in index order leaves ties with the lower index.
        if j < 0 or range_m[i] < range_m[j]:
            owner[p] = i
    return owner


@numba.njit(cache=True, nogil=True)
def organised_pixels(
    azimuth_rad: npt.NDArray[np.float64],
    chan: npt.NDArray[np.int64],
    range_m: npt.NDArray[np.float64],
    xyz: npt.NDArray[np.float64],
    height: int,
    width: int,
) -> tuple[
    npt.NDArray[np.int64],
    npt.NDArray[np.int64],
    npt.NDArray[np.int64],
    npt.NDArray[np.float32],
    npt.NDArray[np.float32],
]:
    """The range image of `projection.organise` from each point's atan2(y, x), channel,
    range and coordinates, in one pass after the arctangent: (N,) row and column, (H*W,)
    owner index (`pixel_owners`), (H*W,) float32 owner range and (H*W, 3) float32 owner
    coordinates (0 where empty). The column is floor(0.5 (1 - a / pi) W) mod W, the
    operations of the numpy form in its order."""
    n = azimuth_rad.shape[0]
    row = np.empty(n, dtype=np.int64)
    col = np.empty(n, dtype=np.int64)
    pixel = np.empty(n, dtype=np.int64)
    for i in range(n):
        u = 0.5 * (-azimuth_rad[i] / np.pi + 1.0) * width
        row[i] = height - 1 - chan[i]
        col[i] = int(math.floor(u)) % width  # u == W is azimuth -pi, i.e. column 0
        pixel[i] = row[i] * width + col[i]
    index = pixel_owners(pixel, range_m, height * width)
    range_img = np.zeros(height * width, dtype=np.float32)
    xyz_img = np.zeros((height * width, 3), dtype=np.float32)
    for p in range(height * width):
        j = index[p]
        if j >= 0:
            range_img[p] = range_m[j]
            xyz_img[p, 0] = xyz[j, 0]
            xyz_img[p, 1] = xyz[j, 1]
            xyz_img[p, 2] = xyz[j, 2]
    return row, col, index, range_img, xyz_img


@numba.njit(cache=True, nogil=True)
def point_ranges(xyz: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], int]:
    """(N,) range in m of each (N, 3) point and how many points have a NaN or infinite
    coordinate, in one pass. The squares are summed x, z, then y: numpy's einsum order, so
    the ranges are the bits `np.sqrt(np.einsum("ij,ij->i", xyz, xyz))` gave."""
    n = xyz.shape[0]
    r = np.empty(n)
    bad = 0
    for i in range(n):
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            bad += 1
        r[i] = math.sqrt((x * x + z * z) + y * y)
    return r, bad


@numba.njit(cache=True, nogil=True)
def image_normals(
    pts: npt.NDArray[np.float64],
    rng: npt.NDArray[np.float64],
    occ: npt.NDArray[np.bool_],
    max_column_gap: int,
    max_depth_jump: float,
    rows_by_line: bool = False,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """(H, W, 3) unnormalised normals and (H, W) validity of an organised image.

    Args:
        pts: (H, W, 3) xyz of the pixel owners in m (0 where empty).
        rng: (H, W) their ranges in m.
        occ: (H, W) True where a point owns the pixel.
        max_column_gap: azimuth neighbours may sit up to this many columns away (wraps).
        max_depth_jump: relative range tolerance of a smooth surface.
        rows_by_line: judge the central difference across rows by where the line through
            the two row neighbours crosses the pixel's beam (`line_crossing_range`) instead
            of by their ranges linearly interpolated: exact on any plane, also on far ground
            that rings a degree or more apart meet metres apart.

    Elevation neighbours are the adjacent rows only and do not wrap.
    """
    height, width = occ.shape
    normal = np.zeros((height, width, 3))
    ok = np.zeros((height, width), dtype=np.bool_)
    diff = np.zeros((2, 3))
    for v in range(height):
        for u in range(width):
            if not occ[v, u]:
                continue
            r0 = rng[v, u]
            good = True
            for axis in range(2):
                max_gap = max_column_gap if axis == 0 else 1
                # Nearest occupied pixel on each side: (row, column, gap), -1 if none.
                nv = -1
                nu = -1
                n_gap = 1.0
                pv = -1
                pu = -1
                p_gap = 1.0
                for sign in (1, -1):
                    for step in range(1, max_gap + 1):
                        if axis == 0:
                            cv, cu = v, (u + sign * step) % width
                        else:
                            cv, cu = v + sign * step, u
                            if cv < 0 or cv >= height:
                                break
                        if occ[cv, cu]:
                            if sign == 1:
                                nv, nu, n_gap = cv, cu, float(step)
                            else:
                                pv, pu, p_gap = cv, cu, float(step)
                            break
                has_next = nv >= 0
                has_prev = pv >= 0
                r_next = rng[nv, nu] if has_next else 0.0
                r_prev = rng[pv, pu] if has_prev else 0.0
                interp = (n_gap * r_prev + p_gap * r_next) / (n_gap + p_gap)
                if rows_by_line and axis == 1 and has_next and has_prev:
                    interp = line_crossing_range(pts, v, u, pv, pu, nv, nu, r0, 0.0, 1.0)
                central = has_next and has_prev and 2.0 * abs(interp - r0) <= max_depth_jump * r0
                jump_next = abs(r_next - r0) if has_next else math.inf
                jump_prev = abs(r_prev - r0) if has_prev else math.inf
                one_sided = min(jump_next, jump_prev) <= max_depth_jump * r0
                if rows_by_line and axis == 1 and not (central or one_sided):
                    side = _row_line_side(pts, occ, v, u, r0, max_depth_jump)
                    one_sided = side != 0
                    jump_next = 0.0 if side == 1 else jump_next
                    jump_prev = 0.0 if side == -1 else jump_prev
                for k in range(3):
                    p_next = pts[nv, nu, k] if has_next else 0.0
                    p_prev = pts[pv, pu, k] if has_prev else 0.0
                    if central:
                        diff[axis, k] = p_next - p_prev
                    elif jump_next <= jump_prev:
                        diff[axis, k] = p_next - pts[v, u, k]
                    else:
                        diff[axis, k] = p_prev - pts[v, u, k]
                good = good and (central or one_sided)
            a0, a1, a2 = diff[0, 0], diff[0, 1], diff[0, 2]
            b0, b1, b2 = diff[1, 0], diff[1, 1], diff[1, 2]
            n0 = a1 * b2 - a2 * b1
            n1 = a2 * b0 - a0 * b2
            n2 = a0 * b1 - a1 * b0
            normal[v, u, 0] = n0
            normal[v, u, 1] = n1
            normal[v, u, 2] = n2
            scale = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) * math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            ok[v, u] = good and math.sqrt(n0 * n0 + n1 * n1 + n2 * n2) > 1e-6 * scale
    return normal, ok


@numba.njit(cache=True, nogil=True)
def on_pixel_surface(
    ok: npt.NDArray[np.bool_],
    range_img: npt.NDArray[np.float64],
    row: npt.NDArray[np.int64],
    col: npt.NDArray[np.int64],
    range_m: npt.NDArray[np.float64],
    max_depth_jump: float,
) -> npt.NDArray[np.bool_]:
    """(N,) whether each point may take its pixel's normal: the pixel's normal is usable
    (`ok`, (H, W)) and the point's range is within max_depth_jump x the owner's range of
    it (the same surface), |r - r_owner| <= jump r_owner as in `modalities`."""
    out = np.empty(row.shape[0], dtype=np.bool_)
    for i in range(row.shape[0]):
        owner = range_img[row[i], col[i]]
        out[i] = ok[row[i], col[i]] and abs(range_m[i] - owner) <= max_depth_jump * owner
    return out


@numba.njit(cache=True, nogil=True)
def pixel_normal_cos(
    normal: npt.NDArray[np.float64],
    row: npt.NDArray[np.int64],
    col: npt.NDArray[np.int64],
    xyz: npt.NDArray[np.float64],
    use: npt.NDArray[np.bool_],
) -> npt.NDArray[np.float64]:
    """(N,) |cos| between each used point's ray and the normal of its pixel, clipped to
    [0, 1]; 0 where `use` is False.

    Args:
        normal: (H, W, 3) unnormalised normals (`image_normals`).
        row, col: (N,) pixel of every point.
        xyz: (N, 3) the points in m, sensor at the origin.
        use: (N,) which points to compute.
    """
    out = np.zeros(row.shape[0])
    for i in range(row.shape[0]):
        if not use[i]:
            continue
        n0 = normal[row[i], col[i], 0]
        n1 = normal[row[i], col[i], 1]
        n2 = normal[row[i], col[i], 2]
        x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        scale = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2) * math.sqrt(x * x + y * y + z * z)
        out[i] = min(abs(n0 * x + n1 * y + n2 * z) / scale, 1.0) if scale > 0.0 else 0.0
    return out


@numba.njit(cache=True, nogil=True)
def line_crossing_range(
    pts: npt.NDArray[np.float64],
    v: int,
    u: int,
    pv: int,
    pu: int,
    nv: int,
    nu: int,
    r0: float,
    share_lo: float,
    share_hi: float,
) -> float:
    """Range along pixel (v, u)'s beam (its point over r0) of the closest approach to the line
    from pixel (pv, pu) (share 0) to (nv, nu) (share 1), m; inf where the line runs along the
    beam or the approach's share of the way lies outside [share_lo, share_hi]. On a plane it
    is r0 itself, at any incidence."""
    d0, d1, d2 = pts[v, u, 0] / r0, pts[v, u, 1] / r0, pts[v, u, 2] / r0
    e0 = pts[nv, nu, 0] - pts[pv, pu, 0]
    e1 = pts[nv, nu, 1] - pts[pv, pu, 1]
    e2 = pts[nv, nu, 2] - pts[pv, pu, 2]
    # Minimising |t d - p - s e| over the beam's t and the line's s (p: the first pixel).
    b = d0 * e0 + d1 * e1 + d2 * e2
    c = e0 * e0 + e1 * e1 + e2 * e2
    dp = d0 * pts[pv, pu, 0] + d1 * pts[pv, pu, 1] + d2 * pts[pv, pu, 2]
    ep = e0 * pts[pv, pu, 0] + e1 * pts[pv, pu, 1] + e2 * pts[pv, pu, 2]
    denom = c - b * b
    if denom <= 1e-12 * c:
        return math.inf
    share = (b * dp - ep) / denom
    if share < share_lo or share > share_hi:
        return math.inf
    return (c * dp - b * ep) / denom


@numba.njit(cache=True, nogil=True)
def _row_line_side(
    pts: npt.NDArray[np.float64],
    occ: npt.NDArray[np.bool_],
    v: int,
    u: int,
    r0: float,
    max_depth_jump: float,
) -> int:
    """+1 (-1) when the pixel continues the line of the two pixels in the next (previous)
    rows of its column (the edge ring of far ground, whose other neighbour lies on another
    surface), else 0. The continuation may reach up to ROW_LINE_REACH times the two pixels'
    spacing."""
    for side in (1, -1):
        v1, v2 = v + side, v + 2 * side
        if v2 < 0 or v2 >= occ.shape[0] or not occ[v1, u] or not occ[v2, u]:
            continue
        r_line = line_crossing_range(pts, v, u, v2, u, v1, u, r0, 1.0, 1.0 + ROW_LINE_REACH)
        if 2.0 * abs(r_line - r0) <= max_depth_jump * r0:
            return side
    return 0
