"""Angular bounds of where a beam can hit a surfel (docs/transfer.md §2).

The cast tests a surfel only against the beams these bounds keep, so they must hold every
beam its exact hit test (`cast._record_hits`: plane coordinates in the unit disk) accepts:
each is exact geometry, widened by BOUND_SLACK against rounding (a unit test compares the
cast with testing every beam). An angle's bound is its tangent (atan x <= x) and a direction's
angle comes from `coarse_atan2`, widened by its error bound: a bound only needs to hold, and the
library's atan2 and asin were a third of the cast's time. Scalars in and out: they run inside
the cast's loop.
"""

from __future__ import annotations

import math

import numba

# The angular bounds of a surfel's hits are widened by this factor against rounding: a beam
# they keep out must never be one its exact test would accept.
BOUND_SLACK = 1.0 + 1e-9
# Axes whose squared part along the normal is below this share of their squared length lie in
# the plane as far as the bounds can tell (their angles change by far less than BOUND_SLACK).
FLAT = 1e-24
# `coarse_atan2` is within this many radians of math.atan2 (its polynomial's error is below
# 2e-6; a unit test checks the bound over the circle).
ATAN2_ERROR_RAD = 1e-5
# The coefficients of t^10, t^8, ..., t^0 of `coarse_atan2`'s polynomial (times t).
_ATAN_POLY = (-0.01172120, 0.05265332, -0.11643287, 0.19354346, -0.33262347, 0.99997726)


@numba.njit(cache=True, nogil=True, inline="always")
def in_plane(
    ax: float,
    ay: float,
    az: float,
    bx: float,
    by: float,
    bz: float,
    nx: float,
    ny: float,
    nz: float,
    gaa: float,
    gbb: float,
    gab: float,
) -> tuple[float, float, float, float, float, float]:
    """The conjugate semi-axes, in the plane of unit normal n, of the region a beam's hit
    must fall in: where the plane coordinates G^-1 (e.A, e.B) (G the Gram matrix of A, B)
    have norm <= 1. With P = the axes' projections onto the plane, that region is P Gp^-1 G
    times the unit disk (Gp = P^T P); for axes in the plane it is (A, B) itself."""
    a_n = ax * nx + ay * ny + az * nz
    b_n = bx * nx + by * ny + bz * nz
    if a_n * a_n <= FLAT * gaa and b_n * b_n <= FLAT * gbb:
        return ax, ay, az, bx, by, bz
    pax, pay, paz = ax - a_n * nx, ay - a_n * ny, az - a_n * nz
    pbx, pby, pbz = bx - b_n * nx, by - b_n * ny, bz - b_n * nz
    # Gp = G minus the parts along n; M = Gp^-1 G, applied to P's columns.
    paa, pbb, pab = gaa - a_n * a_n, gbb - b_n * b_n, gab - a_n * b_n
    det = paa * pbb - pab * pab
    if det <= 0.0:
        return ax, ay, az, bx, by, bz
    inv = 1.0 / det
    m00 = (pbb * gaa - pab * gab) * inv
    m01 = (pbb * gab - pab * gbb) * inv
    m10 = (paa * gab - pab * gaa) * inv
    m11 = (paa * gbb - pab * gab) * inv
    return (
        pax * m00 + pbx * m10,
        pay * m00 + pby * m10,
        paz * m00 + pbz * m10,
        pax * m01 + pbx * m11,
        pay * m01 + pby * m11,
        paz * m01 + pbz * m11,
    )


@numba.njit(cache=True, nogil=True, inline="always")
def angular_radius(
    ax: float,
    ay: float,
    az: float,
    bx: float,
    by: float,
    bz: float,
    ux: float,
    uy: float,
    uz: float,
    r: float,
) -> float:
    """A bound on the angle between the view direction u of an ellipse's centre (at range r)
    and any point of it, radians (its tangent, never smaller); -1 when the ellipse reaches
    the sensor.

    A point is c + d with d = alpha A + beta B, alpha^2 + beta^2 <= 1: d's part along u is
    at most s_par = |(A.u, B.u)| and its part across u at most s_perp, the Frobenius norm of
    A and B without their parts along u, so the angle is at most atan(s_perp / (r - s_par)).
    Far tighter than asin(|A| + |B| / r) on oblique surfaces, whose long axis lies nearly
    along the beam, and exact in what it keeps: no hit is lost."""
    ua = ax * ux + ay * uy + az * uz
    ub = bx * ux + by * uy + bz * uz
    s_par = math.sqrt(ua * ua + ub * ub)
    if r <= s_par:
        return -1.0
    across = ax * ax + ay * ay + az * az - ua * ua + bx * bx + by * by + bz * bz - ub * ub
    return math.sqrt(max(across, 0.0)) / (r - s_par) * BOUND_SLACK


@numba.njit(cache=True, nogil=True, inline="always")
def azimuth_radius(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """A bound on how far in azimuth any point of an ellipse (centre c, semi-axes A, B) lies
    from its centre's, radians (its tangent, never smaller); pi when it reaches round the
    vertical axis.

    In the horizontal basis along (u) and across (v) the centre's azimuth, a point is at
    (rho + d.u, d.v) with |d.v| <= s_v = |(A.v, B.v)| and d.u >= -s_u = -|(A.u, B.u)|, so its
    azimuth differs by at most atan(s_v / (rho - s_u)) <= s_v / (rho - s_u): the ellipse's
    width across the beam, not its elevation extent, sets the columns it can meet."""
    rho = math.sqrt(cx * cx + cy * cy)
    if rho <= 0.0:
        return math.pi
    ux, uy = cx / rho, cy / rho
    au, bu = ax * ux + ay * uy, bx * ux + by * uy
    av, bv = ay * ux - ax * uy, by * ux - bx * uy
    s_u = math.sqrt(au * au + bu * bu)
    if rho <= s_u:
        return math.pi
    return math.sqrt(av * av + bv * bv) / (rho - s_u) * BOUND_SLACK


@numba.njit(cache=True, nogil=True, inline="always")
def coarse_atan2(y: float, x: float) -> float:
    """atan2(y, x) within ATAN2_ERROR_RAD, radians in [-pi, pi] (0 at the origin); the sign of
    a zero y is ignored, so -pi comes back as pi: callers reduce angles modulo 2 pi.

    The octant's ratio t in [0, 1] goes through the degree-11 odd minimax polynomial of
    atan on [0, 1] (Hastings, Approximations for Digital Computers, 1955)."""
    ax, ay = abs(x), abs(y)
    big = max(ax, ay)
    if big == 0.0:
        return 0.0
    t = min(ax, ay) / big
    t2 = t * t
    poly = 0.0
    for c in _ATAN_POLY:
        poly = poly * t2 + c
    a = t * poly
    if ay > ax:
        a = 0.5 * math.pi - a
    if x < 0.0:
        a = math.pi - a
    return -a if y < 0.0 else a
