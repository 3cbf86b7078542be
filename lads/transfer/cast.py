"""Ray-cast a target sensor against surfels (docs/transfer.md §2).

The target's beams are a grid: its elevation table (rows) times equally spaced azimuths
(columns, `azimuth_offset_rad` + (j + 0.5) 2 pi / W). Each surfel is splatted onto the beams
its disk can meet (the rows and columns within its angular radius), and each of those beams is
intersected exactly with the disk's plane: the nearest hit inside a disk wins the beam. The
range is therefore exact on planar surfaces whatever the source's sampling, and occlusion is
the target's own.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from lads.transfer.blend import blend_hits
from lads.transfer.bounds import (
    ATAN2_ERROR_RAD,
    angular_radius,
    azimuth_radius,
    coarse_atan2,
    in_plane,
)
from lads.transfer.carve import FreeSpace, carved
from lads.transfer.surfels import Surfels

F64 = npt.NDArray[np.float64]
# The surfel fields the cast reads: its shape (moved into the target frame as it is read) and
# what each hit votes with in the blend.
SHAPE_FIELDS = ("centre", "normal", "axis_a", "axis_b", "radius_m")
VOTE_FIELDS = ("albedo", "weight", "retro")


@dataclass(frozen=True, slots=True)
class BeamHits:
    """The nearest disk hit of every target beam.

    Attributes:
        range_m: (H, W) float64 range of the hit along the beam, m; inf without a hit.
        owner: (H, W) int64 surfel that owns the beam, -1 without a hit.
        cos_incidence: (H, W) float64 |cos| between beam and the owner's normal (0 empty).
        reflectivity: (H, W) float64 reflectivity the beam sees: each surfel that voted for
            its depth predicts albedo x cos(beam, its normal) (retro-reflectors: albedo), and
            the predictions are blended with the depth weights times the surfel's trust
            (its source's cos^2: oblique views, whose albedo is least certain, count least);
            0 empty.
        elevation_rad: (H,) beam elevations, channel 0 (lowest) first.
        azimuth_rad: (W,) beam azimuths in the target frame.
    """

    range_m: F64
    owner: npt.NDArray[np.int64]
    cos_incidence: F64
    reflectivity: F64
    elevation_rad: F64
    azimuth_rad: F64

    def directions(self) -> F64:
        """(H, W, 3) unit beam directions in the target frame."""
        ce, se = np.cos(self.elevation_rad)[:, None], np.sin(self.elevation_rad)[:, None]
        ca, sa = np.cos(self.azimuth_rad)[None, :], np.sin(self.azimuth_rad)[None, :]
        return np.stack(np.broadcast_arrays(ce * ca, ce * sa, se), axis=-1)


def cast_parts(
    parts: Sequence[Surfels | dict[str, npt.NDArray[np.generic]]],
    kept: Sequence[npt.NDArray[np.int64]],
    to_target: Sequence[F64],
    elevation_rad: npt.ArrayLike,
    columns: int,
    *,
    azimuth_offset_rad: float = 0.0,
    max_range_m: float = np.inf,
    depth_tol_m: float = 0.1,
    depth_tol_share: float = 0.01,
    view_sigma_rad: float = math.inf,
    free: FreeSpace | None = None,
) -> BeamHits:
    """The nearest surfel hit of each beam of a (len(elevation_rad), columns) grid, against
    the `kept` surfels of several parts (the scans of a window).

    Args:
        parts: surfels, or their fields SHAPE_FIELDS and VOTE_FIELDS by name, each in its
            own scan's frame.
        kept: (K_p,) int64 increasing rows of each part to cast against.
        to_target: (4, 4) pose of each part in the target sensor's frame (the sensor at the
            origin); the compiled pass moves each surfel as it reads it, so the window is
            never copied into one array.
        elevation_rad: (H,) ascending beam elevations, radians.
        columns: W azimuth samples per revolution (>= 4).
        azimuth_offset_rad: azimuth of the grid's start; column j looks along
            azimuth_offset_rad + (j + 0.5) 2 pi / W.
        max_range_m: disks whose nearest point lies beyond this are skipped.
        depth_tol_m, depth_tol_share: the depth window of the blend (`blend.blend_hits`).
        view_sigma_rad: a surfel's reflectivity vote counts exp(-(angle / sigma)^2) less
            where the beam looks at it from another direction than its own scan did (its
            albedo carries its normal's error, which cancels only along its own view);
            inf: every view counts the same.
        free: what the centre scan saw; hits in its free space are dropped before the
            blend (`lads.transfer.carve`). None: every hit counts.

    Returns:
        BeamHits; a beam's surfel (owner) is its index among the kept surfels of all parts,
        in order.
    """
    el = np.asarray(elevation_rad, dtype=np.float64)
    step = 2.0 * math.pi / int(columns)
    az = azimuth_offset_rad + (np.arange(int(columns)) + 0.5) * step
    best = np.full((len(el), int(columns)), np.inf)
    best_cos = np.ones((len(el), int(columns)))
    record = (el, azimuth_offset_rad, columns, max_range_m, best, best_cos, view_sigma_rad)
    hits = _record_parts(parts, kept, to_target, *record).trimmed()
    best, best_cos, floor = carved(free, best, best_cos, hits[:3], el, az)
    t, owner, refl, cos = blend_hits(  # type: ignore[call-arg]
        best, best_cos, floor, *hits, depth_tol_m, depth_tol_share
    )
    return BeamHits(t, owner, cos, refl, el, az)


def _record_parts(
    parts: Sequence[Surfels | dict[str, npt.NDArray[np.generic]]],
    kept: Sequence[npt.NDArray[np.int64]],
    to_target: Sequence[F64],
    el: F64,
    azimuth_offset_rad: float,
    columns: int,
    max_range_m: float,
    best: F64,
    best_cos: F64,
    view_sigma_rad: float,
) -> _HitBuffers:
    """Pass 1 over all parts: the hit records; updates (H, W) best (m), best_cos in place."""
    total = sum(len(k) for k in kept)
    buffers = _HitBuffers.empty(2 * total + 1024)
    offset = 0
    for part, idx, pose in zip(parts, kept, to_target, strict=True):
        g = _fields(part, SHAPE_FIELDS + VOTE_FIELDS)
        turn = np.ascontiguousarray(np.asarray(pose, np.float64)[:3, :3])
        shift = np.ascontiguousarray(np.asarray(pose, np.float64)[:3, 3])
        # numba's Dispatcher stub takes fewer arguments than the compiled functions do.
        buffers = _HitBuffers(
            *_record_hits(  # type: ignore[call-arg]
                g["centre"],
                g["normal"],
                g["axis_a"],
                g["axis_b"],
                g["radius_m"],
                g["albedo"],
                g["weight"],
                g["retro"],
                np.asarray(idx, np.int64),
                turn,
                shift,
                offset,
                el,
                float(azimuth_offset_rad),
                int(columns),
                float(max_range_m),
                _view_k(view_sigma_rad),
                best,
                best_cos,
                *buffers.arrays(),
                buffers.n,
            )
        )
        offset += len(idx)
    return buffers


def _fields(part: Any, names: Sequence[str]) -> dict[str, Any]:
    return {f: part[f] if isinstance(part, dict) else getattr(part, f) for f in names}


@dataclass(frozen=True, slots=True)
class _HitBuffers:
    """The hit records of `_record_hits` (beam, distance, |cos|, weight, surfel, the
    reflectivity the surfel predicts for the beam and its trust) and their count `n`; the
    arrays grow inside the compiled pass and come back from it."""

    pix: npt.NDArray[np.int64]
    t: F64
    cos: F64
    w: F64
    i: npt.NDArray[np.int64]
    seen: F64
    trust: F64
    n: int

    @staticmethod
    def empty(cap: int) -> _HitBuffers:
        return _HitBuffers(
            np.empty(cap, np.int64),
            np.empty(cap),
            np.empty(cap),
            np.empty(cap),
            np.empty(cap, np.int64),
            np.empty(cap),
            np.empty(cap),
            0,
        )

    def arrays(self) -> tuple[Any, ...]:
        return self.pix, self.t, self.cos, self.w, self.i, self.seen, self.trust

    def trimmed(self) -> tuple[Any, ...]:
        return tuple(a[: self.n] for a in self.arrays())


@numba.njit(cache=True, nogil=True)
def _record_hits(
    centre: F64,
    normal: F64,
    axis_a: F64,
    axis_b: F64,
    radius: F64,
    albedo: F64,
    trust: F64,
    retro: npt.NDArray[np.bool_],
    idx: npt.NDArray[np.int64],
    turn: F64,
    shift: F64,
    offset: int,
    el: F64,
    az0: float,
    columns: int,
    max_range: float,
    view_k: float,
    best: F64,
    best_cos: F64,
    hit_pix: npt.NDArray[np.int64],
    hit_t: F64,
    hit_cos: F64,
    hit_w: F64,
    hit_i: npt.NDArray[np.int64],
    hit_seen: F64,
    hit_trust: F64,
    n: int,
) -> tuple[npt.NDArray[np.int64], F64, F64, F64, npt.NDArray[np.int64], F64, F64, int]:
    """Pass 1 of the cast, for one part: the hits of its surfels `idx`, moved by (turn,
    shift) into the target frame, updating each beam's nearest hit (best, best_cos).

    A beam meets a surfel where it crosses the surfel's plane at (alpha, beta) in the basis
    of its semi-axes with alpha^2 + beta^2 <= 1. Each hit appends a record: beam (k * W + j),
    distance, |cos|, weight 1 - alpha^2 - beta^2, surfel (offset + its place in idx), the
    reflectivity the surfel predicts (albedo x |cos|; a retro-reflector's albedo) and its
    trust. Returns the record arrays (grown when full) and their count. Scalars only inside the
    loops: a numba helper taking arrays costs far more than its work here."""
    step = 2.0 * math.pi / columns
    cos_el, sin_el = np.cos(el), np.sin(el)
    az = az0 + (np.arange(columns) + 0.5) * step
    cos_az, sin_az = np.cos(az), np.sin(az)
    cap = hit_pix.shape[0]
    for ii in range(idx.shape[0]):
        i = idx[ii]
        vx, vy, vz = _turned(turn, centre[i, 0], centre[i, 1], centre[i, 2])
        cx, cy, cz = vx + shift[0], vy + shift[1], vz + shift[2]
        nx, ny, nz = _turned(turn, normal[i, 0], normal[i, 1], normal[i, 2])
        rad = radius[i]
        r = math.sqrt(cx * cx + cy * cy + cz * cz)
        if r <= rad or r - rad > max_range:
            continue
        ax, ay, az_ = _turned(turn, axis_a[i, 0], axis_a[i, 1], axis_a[i, 2])
        bx, by, bz = _turned(turn, axis_b[i, 0], axis_b[i, 1], axis_b[i, 2])
        gaa = ax * ax + ay * ay + az_ * az_
        gbb = bx * bx + by * by + bz * bz
        gab = ax * bx + ay * by + az_ * bz
        # The hits of a beam are where its plane coordinates (alpha, beta) fall in the unit
        # disk: the ellipse whose in-plane conjugate semi-axes `bounds.in_plane` gives (the axes
        # themselves, unless a grazing surfel's stretching stopped at min_cos).
        pax, pay, paz, pbx, pby, pbz = in_plane(ax, ay, az_, bx, by, bz, nx, ny, nz, gaa, gbb, gab)
        half = angular_radius(pax, pay, paz, pbx, pby, pbz, cx / r, cy / r, cz / r, r)
        if half < 0.0:
            continue
        # The bounds are widened by the coarse angle's error: they only need to hold.
        half += ATAN2_ERROR_RAD
        e_i = coarse_atan2(cz, math.sqrt(cx * cx + cy * cy))
        lo = np.searchsorted(el, e_i - half)
        hi = lo  # the rows a surfel spans are few: step up instead of a second search
        top = e_i + half
        while hi < el.shape[0] and el[hi] <= top:
            hi += 1
        if lo >= hi:
            continue
        w = azimuth_radius(pax, pay, pbx, pby, cx, cy)
        if w >= math.pi:
            j0, count = 0, columns
        else:
            a_i = coarse_atan2(cy, cx)
            w += ATAN2_ERROR_RAD
            j0 = int(math.floor((a_i - w - az0) / step - 0.5)) + 1
            count = int(math.floor((a_i + w - az0) / step - 0.5)) - j0 + 1
            count = min(max(count, 0), columns)
        c_dot_n = cx * nx + cy * ny + cz * nz
        det = gaa * gbb - gab * gab
        if det <= 1e-18:
            continue
        j0 %= columns
        view_norm = math.sqrt(vx * vx + vy * vy + vz * vz)
        albedo_i, retro_i, trust_i = albedo[i], retro[i], trust[i]
        for k in range(lo, hi):
            j = j0 - 1
            for _ in range(count):
                j = 0 if j == columns - 1 else j + 1
                dx = cos_el[k] * cos_az[j]
                dy = cos_el[k] * sin_az[j]
                dz = sin_el[k]
                denom = dx * nx + dy * ny + dz * nz
                if abs(denom) < 1e-9:
                    continue
                t = c_dot_n / denom
                if t <= 0.0 or t > max_range:
                    continue
                ex, ey, ez = t * dx - cx, t * dy - cy, t * dz - cz
                qa = ex * ax + ey * ay + ez * az_
                qb = ex * bx + ey * by + ez * bz
                alpha = (gbb * qa - gab * qb) / det
                beta = (gaa * qb - gab * qa) / det
                d2 = alpha * alpha + beta * beta
                if d2 > 1.0:
                    continue
                if t < best[k, j]:
                    best[k, j] = t
                    best_cos[k, j] = abs(denom)
                if n == cap:
                    cap *= 2
                    hit_pix = _grown_int(hit_pix, cap)
                    hit_t = _grown(hit_t, cap)
                    hit_cos = _grown(hit_cos, cap)
                    hit_w = _grown(hit_w, cap)
                    hit_i = _grown_int(hit_i, cap)
                    hit_seen = _grown(hit_seen, cap)
                    hit_trust = _grown(hit_trust, cap)
                hit_pix[n] = k * columns + j
                hit_t[n] = t
                hit_cos[n] = abs(denom)
                hit_w[n] = 1.0 - d2 + 1e-6
                hit_i[n] = offset + ii
                # Each surfel predicts the beam's reflectivity with its own normal, so a
                # normal error cancels against its source's when the views agree.
                hit_seen[n] = albedo_i if retro_i else albedo_i * abs(denom)
                hit_trust[n] = trust_i
                if view_k > 0.0:
                    # 1 - cos(angle) between the beam and the surfel's own scan's view of it
                    off = 1.0 - (dx * vx + dy * vy + dz * vz) / view_norm
                    hit_trust[n] *= math.exp(-view_k * off)
                n += 1
    return hit_pix, hit_t, hit_cos, hit_w, hit_i, hit_seen, hit_trust, n


def _view_k(view_sigma_rad: float) -> float:
    """exp(-(angle / sigma)^2) ~ exp(-k (1 - cos angle)) with k = 2 / sigma^2 (0: off)."""
    return 0.0 if not math.isfinite(view_sigma_rad) else 2.0 / (view_sigma_rad * view_sigma_rad)


@numba.njit(cache=True, nogil=True, inline="always")
def _turned(m: F64, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(m @ (x, y, z)) of a 3 x 3 matrix, as three scalars."""
    return (
        m[0, 0] * x + m[0, 1] * y + m[0, 2] * z,
        m[1, 0] * x + m[1, 1] * y + m[1, 2] * z,
        m[2, 0] * x + m[2, 1] * y + m[2, 2] * z,
    )


@numba.njit(cache=True, nogil=True)
def _grown(a: F64, cap: int) -> F64:
    out = np.empty(cap)
    out[: a.shape[0]] = a
    return out


@numba.njit(cache=True, nogil=True)
def _grown_int(a: npt.NDArray[np.int64], cap: int) -> npt.NDArray[np.int64]:
    out = np.empty(cap, dtype=np.int64)
    out[: a.shape[0]] = a
    return out
