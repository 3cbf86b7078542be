"""Seeded generator of the concealed-effect benchmark of `lads diagnose` (docs/diagnose.md §6).

`generate_case(case, base, seed, out_dir)` writes, under `out_dir`:

    sim/        tree A, the base dataset's own format (what the tool gets as --sim)
    real/       tree B = T_theta(A) plus noise (what the tool gets as --real)
    oracle/     tree A with T_theta applied, no noise, no object spread, no dropout (rows of A)
    truth.json  the hidden effects in the tool's parametrisation (catalogue.py), never in a tree

The trees hold scans and labels only (no calib/times/json/yaml): the tool sees nothing else.
Only `lads.diagnose.effects.catalogue` (metadata) is imported from `lads.diagnose`; every hidden
effect is implemented here, independently of the tool.

Bases and scans
---------------
* "semantickitti": the 3 labelled frames of ../shared/data/semantickitti (HDL-64E, remission
  in [0, 0.99], 0.01 steps). Trees: `sequences/00/velodyne/NNNNNN.bin` (float32 x, y, z,
  remission) and `sequences/00/labels/NNNNNN.label` (uint32). Scans 000000-000002 are the
  real frames; 000003-000005 are the same frames rotated about z by a random yaw (same points,
  each ring's rows re-sorted by the rotated azimuth so the file stays "ring by ring, one
  rotation each" and `lads.sensors.measure.rings_from_scan_order` still finds the rings).
* "nuscenes": the one keyframe of ../shared/data/nuscenes (HDL-32E, calibrated reflectivity,
  integers 0-255, ring column). Trees: `samples/LIDAR_TOP/<name>.pcd.bin` (float32 x, y, z,
  intensity, ring). Scan 0 keeps the real name, copies 1-5 are rotated by a random yaw and
  named with the keyframe timestamp + k * 500000 us. Unlabelled, so K7, K8, K11 and K20 (class
  cases) raise ValueError; K14 uses a fitted ground plane instead of ground classes.
* Points nearer than MIN_RANGE_M = 1 m are dropped first (nuScenes stores ~8000 ego-body and
  invalid returns at 0-1 m; the nearest KITTI return is 1.3 m).
* `max_points` subsamples every scan (random rows, file order kept) after the copies are made;
  A, B and the oracle hold the same rows (B minus the rows it drops).
* Per-point geometry is computed once per real frame at full resolution: the ring (KITTI:
  scan order; nuScenes: ring column, 0 = lowest beam), cos(theta) (`incidence_cos` with that
  ring; ground points: the least-squares plane of their 10 m tile, `ground_plane_cos`), the
  edge distance in beams (per ring, in azimuth order, to the nearest neighbour pair whose
  range jumps by > 1 m or whose azimuth gap exceeds 4 beam spacings) and object ids
  (SemanticKITTI instance ids where present, else a 2 m voxel per class; each scan, copies
  included, has its own objects and so its own object reflectance draws). The hidden
  effects use this "true" geometry; the tool estimates its own from the (possibly
  subsampled) trees.

Modes (docs/diagnose.md §6.2)
-------------------------
Every term acts in the catalogue's domain y = ln(I + h), h = half a quantisation step, I in
stored units (KITTI 0-0.99, nuScenes 0-255), so the truth parameters are exactly the
parameters of report.json. Noise is Gaussian in y (log-normal in I) with zero mean. t, the
sum of a case's ln-terms, is centred to mean 0 over the points: the overall level is the
sensor gain's (C0), not the hidden effect's.
* M1 (real -> real): A = the real scan. B = q(exp(ln(I_A + h) + t + eps) - h), eps ~
  N(0, sigma_n^2), sigma_n in [0.05, 0.2]; q re-quantises to the encoding (KITTI: 0.01 steps
  clipped to [0, 0.99]; nuScenes: integers 0-255). No random dropout.
* M2 (simple sim -> real-like): x_A = c * rho_class * max(cos theta, 0.05) / R^2 on the real
  geometry (rho from `reflectance_for_labels`, 0.2 unlabelled), A = q(x_A). c puts the median
  at 0.25 (KITTI) or 20 (nuScenes) unless that saturates more than 2 % of the points; then
  the 98th percentile sits at the top of the encoding (KITTI: median ~0.09). B is built from
  the unquantised x_A: y_B = ln(x_A + h) + t + o_object + eps, o_object ~ N(0, sigma_obj^2)
  per object (sigma_obj in [0.2, 0.4]), then quantised; plus random (MCAR) dropout of a
  fraction in [0, 0.03] of B's points, which is not an effect (recorded as random_dropout).

Effect sizes (docs/diagnose.md §6.3)
--------------------------------
sigma, the per-point noise of the band, is sigma_n (M1) or sqrt(sigma_n^2 + sigma_obj^2)
(M2); K19 uses its sigma at the median range. The hidden term's RMS is taken after removing
its global mean (a gain the tool may always fit, C0), over the effect's domain (all points;
the class of a class-confined effect; the affected rings of K6; the sector of K15; points
within 2 beams of an edge for K17). Noise and parameters are drawn jointly and redrawn (up to
MAX_TRIES) until every banded effect has RMS / sigma in [0.3, 2]; if no draw qualifies the
first draw is kept and truth.json records in_band: false (e.g. K8's x5-x50 retro gain is far
outside the band by design, and K14's fixed p = 1 in M1). Dropout-only K10 is not banded
(its size is the drop fraction, 3-15 %).

Cases (docs/diagnose.md §6.4) and truth (catalogue parametrisation)
---------------------------------------------------------------
K1  t = -dn ln R; dn in [0.2, 1.0] (KITTI, raw sensor) or uniform over [0.2, 1.0] U [-2, -1.5]
    (nuScenes, compensated sensor)                          -> C1 delta_n = dn (prior range
    for the parameter error: the drawn branch)
K2  t = -2 alpha R, alpha in [0.002, 0.03]                  -> C5 alpha_per_m
K3  t = -ln(1 + (R0/R)^k), R0 in [2, 8] m, k in [2, 6]      -> C2 r0_m, k
K4  Lambert -> cos^p (p in [0.5, 2]): t = (p - 1) ln cos    -> C3 p_extra = p - 1
    or Oren-Nayar (sigma in [0.15, 0.5] rad): t = ln(A + B sin^2/cos) -> C3, params {} (ID only)
K5  t = ln g_ring, ln g ~ N(0, s^2) per ring, s in [0.05, 0.3], centred -> C4 ln_gain_by_ring
K6  1-3 rings (>= 0.5 % of points each) with g in [0.6, 0.85] -> C4 ln_gain_by_ring (centred,
    list over all rings), "rings" = the affected rings
K7  t = ln(1 + k_s cos^(m-1)) on class car, k_s in [0.5, 3], m in [20, 200] -> C3s k_s, m
K8  t = ln_gain - ln cos on class traffic-sign, gain x[5, 50] -> C3r ln_gain (flagged
    unidentifiable when more than half of the sign points saturate at the encoding's top)
K9  I -> min(FS (I/FS)^gamma + b, i_max) applied to the noisy intensity before quantisation
    (FS = full scale: 1 KITTI, 100 nuScenes), gamma in [0.6, 0.9], b in [0, 4] steps, i_max in
    [150, 230]/255 of the 8-bit range (KITTI [0.59, 0.90], nuScenes [150, 230]) -> C9 gamma,
    offset, i_max (i_max flagged unidentifiable when < 0.5 % of points reach it)
K10 dropout only: P(ret) = Phi((mu - ln tau) / s), mu = ln(I_oracle + h), s in [0.2, 1],
    ln tau solved so a fraction in [0.03, 0.15] drops; intensity unchanged -> D1 ln_tau, s
K11 wet road and sidewalk: t = ln(1 - f + f F(theta)) with F ~ 0 (a water film returns
    nothing to a monostatic sensor off the normal), f in [0.3, 0.8]; those points with
    theta > theta_c in [60, 80] deg are dropped -> C7 f, theta_c_deg
K12 K2 + K5                                                  -> C5 + C4
K13 K3 + K1                                                  -> C2 + C1
K14 Lambert missing on ground-only trees (KITTI classes 40, 44, 48, 49, 60, 72; nuScenes a
    fitted ground plane): t = -ln cos -> C3 p_extra = -1; accept_ambiguity {C1, C3},
    {C1, C3, C4}, {C3, C4}, {C1, C3, C4, C9}, {C3, C9} (K14_ACCEPT)
K15 azimuth sector [start, start + width), width in [10, 40] deg, factor 1 - a in [0.5, 0.8],
    plus a random drop of a fraction in [0.05, 0.3] of the sector's points
    -> C11 start_deg (atan2(y, x) in [0, 360)), width_deg, a, drop_fraction
K16 scan AGC: A's scans first get a scene brightness exp(u_s), u_s ~ N(0, 0.3^2) (so scans
    differ in mean, what an AGC reacts to), then t = -beta (ln m_s - mean_s ln m_s), m_s the
    mean stored intensity of scan s in A, beta in [0.3, 1]  -> C10 beta
K17 t = ln(1 - a exp(-e / e0)), e = edge distance in beams, a in [0.3, 0.7], e0 in [0.5, 1.5]
    -> C8 a, e0_beams
K18 no effect, noise only                                    -> effects [], homoscedastic
K19 no effect, sigma(R) = sigma_n (R / R_median)^b, b in [0.5, 1], capped at 1.0
    -> effects [], noise kind heteroscedastic
K20 vegetation (class 70) reflectance x[0.6, 1.5]           -> C6 ln_scale_vegetation
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.special import ndtr

from benchmarks.common import SHARED_DATA
from lads.diagnose.effects.catalogue import CATALOGUE
from lads.physics.materials import class_materials, reflectance_for_labels
from lads.physics.modalities import incidence_cos
from lads.readers import get_reader
from lads.sensors.measure import rings_from_scan_order
from lads.sensors.profile import IntensityEncoding, load_profile

BASE_ROOTS = {"semantickitti": SHARED_DATA / "semantickitti", "nuscenes": SHARED_DATA / "nuscenes"}
PROFILES = {"semantickitti": "hdl64e", "nuscenes": "hdl32e"}
BASES = ("semantickitti", "nuscenes")
MODES = ("M1", "M2")
CASES = tuple(f"K{i}" for i in range(1, 21))
CLASS_CASES = frozenset({"K7", "K8", "K11", "K20"})

MIN_RANGE_M = 1.0
COPIES = {"semantickitti": 2, "nuscenes": 6}  # scans per real frame, the original included
NUSCENES_STEP_US = 500_000
COS_FLOOR = 0.05
NOISE_SIGMA = (0.05, 0.2)
OBJECT_SIGMA = (0.2, 0.4)
RANDOM_DROP = (0.0, 0.03)
BAND = (0.3, 2.0)
MAX_TRIES = 200
M2_MEDIAN = {"semantickitti": 0.25, "nuscenes": 20.0}
M2_MAX_SATURATED = 0.02
VOXEL_M = 2.0
GROUND_TILE_M = 10.0
GROUND_TILE_MIN = 30
EDGE_JUMP_M = 1.0
EDGE_GAP_SPACINGS = 4.0
EDGE_FAR = 99.0
GROUND_CLASSES = (40, 44, 48, 49, 60, 72)
CAR, SIGN, ROAD, SIDEWALK, VEGETATION = 10, 81, 40, 48, 70
AGC_SCENE_SIGMA = 0.3
HETERO_SIGMA_CAP = 1.0
LABEL_SET = "semantickitti"


# The explanations ground-only data cannot tell apart (docs/diagnose.md §2 item 3, §5.4): on flat
# ground cos theta = h / R and each ring meets the ground at one range, so a range exponent,
# an incidence law and per-ring gains are one function of range. So is the encoding's gamma
# (C9), added 2026-11-25: ln I_sim = ln(c rho h) - 3 ln R there, so gamma = 2/3 reproduces
# K14's missing -ln cos = ln R - ln h up to the few ground classes' reflectances.
K14_ACCEPT = [["C1", "C3"], ["C1", "C3", "C4"], ["C3", "C4"], ["C1", "C3", "C4", "C9"],
              ["C3", "C9"]]  # fmt: skip

CASE_DESCRIPTIONS = {
    "K1": "range exponent change",
    "K2": "atmospheric attenuation",
    "K3": "near-range overlap",
    "K4": "Lambert -> cos^p or Oren-Nayar",
    "K5": "per-ring gains, all rings",
    "K6": "one to three rings",
    "K7": "specular lobe on car",
    "K8": "retro-reflection on sign",
    "K9": "encoding gamma/offset/clip",
    "K10": "dropout only (threshold)",
    "K11": "wet road and sidewalk",
    "K12": "attenuation + ring gains",
    "K13": "near-range + range exponent",
    "K14": "Lambert missing, ground only",
    "K15": "azimuth-sector blockage",
    "K16": "scan-level AGC",
    "K17": "mixed pixels at edges",
    "K18": "null: noise only",
    "K19": "heteroscedastic noise only",
    "K20": "vegetation reflectance mismatch",
}


def cases_for(base: str) -> list[str]:
    """The cases available on a base (nuScenes is unlabelled: no class-confined cases)."""
    _check_base(base)
    return [c for c in CASES if base == "semantickitti" or c not in CLASS_CASES]


def _check_base(base: str) -> None:
    if base not in BASES:
        raise ValueError(f"unknown base {base!r}; expected one of {BASES}")


def _effect(id_: str, params: dict[str, Any], **extra: Any) -> dict[str, Any]:
    entry = {"id": id_, "key": CATALOGUE[id_].key, "params": params}
    entry.update(extra)
    return entry


def _rng(*parts: object) -> np.random.Generator:
    """A Generator seeded from a hash of `parts` (never global state)."""
    digest = hashlib.sha256("|".join(str(p) for p in parts).encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:16], "little"))


# ----------------------------------------------------------------------------------------
# Base frames (full resolution, cached per process)


@dataclass(frozen=True)
class BaseFrame:
    """One real frame with its true per-point geometry, all (N,) after the range cut."""

    name: str  # file name of the real scan
    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    labels: npt.NDArray[np.uint32] | None
    ring_column: npt.NDArray[np.float32] | None  # nuScenes only
    ring: npt.NDArray[np.int64]
    cos: npt.NDArray[np.float64]
    edge: npt.NDArray[np.float64]
    obj: npt.NDArray[np.int64]  # object id, unique within the frame
    ground: npt.NDArray[np.bool_]


@functools.lru_cache(maxsize=2)
def load_base(base: str) -> tuple[BaseFrame, ...]:
    """The real frames of a base with ring, cos(theta), edge distance, objects, ground."""
    _check_base(base)
    root = BASE_ROOTS[base]
    profile = load_profile(PROFILES[base])
    frames = []
    if base == "semantickitti":
        reader = get_reader("semantickitti", root)
        for item in reader.items():
            fr = reader.read(item)
            xyz = np.ascontiguousarray(fr.xyz, dtype=np.float32)
            keep = np.linalg.norm(xyz.astype(np.float64), axis=1) >= MIN_RANGE_M
            xyz = xyz[keep]
            labels = np.asarray(fr.labels, dtype=np.uint32)[keep]
            intensity = np.asarray(fr.intensity, dtype=np.float32)[keep]
            ring = rings_from_scan_order(xyz, profile.channels)
            cls = (labels & 0xFFFF).astype(np.int64)
            frames.append(
                _base_frame(
                    Path(item.relpath).name,
                    xyz,
                    intensity,
                    labels,
                    None,
                    ring,
                    cls,
                    profile,
                    ground=np.isin(cls, GROUND_CLASSES),
                )
            )
    else:
        for path in sorted((root / "samples" / "LIDAR_TOP").glob("*.pcd.bin")):
            pts = np.fromfile(path, dtype="<f4").reshape(-1, 5)
            keep = np.linalg.norm(pts[:, :3].astype(np.float64), axis=1) >= MIN_RANGE_M
            pts = pts[keep]
            xyz = np.ascontiguousarray(pts[:, :3])
            ring = pts[:, 4].astype(np.int64)
            cls = np.full(len(pts), -1, dtype=np.int64)
            frames.append(
                _base_frame(
                    path.name,
                    xyz,
                    np.ascontiguousarray(pts[:, 3]),
                    None,
                    np.ascontiguousarray(pts[:, 4]),
                    ring,
                    cls,
                    profile,
                    ground=_ground_plane(xyz),
                )
            )
    if not frames:
        raise FileNotFoundError(f"no {base} scans under {root}")
    return tuple(frames)


def _base_frame(
    name: str,
    xyz: npt.NDArray[np.float32],
    intensity: npt.NDArray[np.float32],
    labels: npt.NDArray[np.uint32] | None,
    ring_column: npt.NDArray[np.float32] | None,
    ring: npt.NDArray[np.int64],
    cls: npt.NDArray[np.int64],
    profile: Any,
    *,
    ground: npt.NDArray[np.bool_],
) -> BaseFrame:
    cos = ground_plane_cos(xyz, ground, incidence_cos(xyz, profile, channel=ring))
    edge = edge_distance(xyz, ring)
    if labels is not None:
        instance = labels >> 16
        key_inst = labels.astype(np.int64)
    else:
        instance = np.zeros(len(xyz), dtype=np.uint32)
        key_inst = np.zeros(len(xyz), dtype=np.int64)
    vox = np.floor(xyz.astype(np.float64) / VOXEL_M).astype(np.int64) + 4096
    key_vox = ((cls + 1) << 42) | (vox[:, 0] << 28) | (vox[:, 1] << 14) | vox[:, 2]
    keys = np.where(instance > 0, -1 - key_inst, key_vox)
    _, obj = np.unique(keys, return_inverse=True)
    return BaseFrame(
        name, xyz, intensity, labels, ring_column, ring, cos, edge, obj.astype(np.int64), ground
    )


def edge_distance(xyz: npt.ArrayLike, ring: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Distance in beams to the nearest edge along each ring, (N,) float64.

    Per ring, points in azimuth order; the pair (i, i+1) (circular) is an edge when their
    ranges differ by > EDGE_JUMP_M or their azimuth gap exceeds EDGE_GAP_SPACINGS median
    spacings (missing returns). Both points of an edge pair have distance 0. Rings with
    fewer than 3 points get EDGE_FAR.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    ring = np.asarray(ring, dtype=np.int64)
    r = np.linalg.norm(xyz, axis=1)
    az = np.arctan2(xyz[:, 1], xyz[:, 0])
    order = np.lexsort((az, ring))
    out = np.full(len(xyz), EDGE_FAR)
    bounds = np.flatnonzero(np.diff(ring[order])) + 1
    for idx in np.split(order, bounds):
        n = len(idx)
        if n < 3:
            continue
        rr, aa = r[idx], az[idx]
        gap = np.mod(np.roll(aa, -1) - aa, 2 * np.pi)
        spacing = float(np.median(gap))
        jump = (np.abs(np.roll(rr, -1) - rr) > EDGE_JUMP_M) | (gap > EDGE_GAP_SPACINGS * spacing)
        edge = jump | np.roll(jump, 1)
        e = np.flatnonzero(edge)
        if e.size == 0:
            continue
        pos = np.arange(n)
        j = np.searchsorted(e, pos)
        right = e[j % e.size]
        left = e[(j - 1) % e.size]
        d = np.minimum(np.mod(right - pos, n), np.mod(pos - left, n))
        out[idx] = np.minimum(d, EDGE_FAR)
    return out


def ground_plane_cos(
    xyz: npt.ArrayLike, ground: npt.ArrayLike, image_cos: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """(N,) float64 cos(theta), ground points' from the plane of their GROUND_TILE_M tile.

    The truth's incidence is the surface's. On the ground beyond ~20 m the neighbouring rings
    are metres apart, and a normal from image neighbours is off by 5-20 degrees
    (benchmarks/ground_incidence.py, full KITTI scans): as truth it planted a random term on
    far ground that no incidence law can fit. A least-squares plane of the tile's ground
    returns (>= GROUND_TILE_MIN points; else the image normal stays) is the road's own
    orientation. Other points keep the image normal."""
    p = np.asarray(xyz, dtype=np.float64)
    out = np.asarray(image_cos, dtype=np.float64).copy()
    rows = np.flatnonzero(np.asarray(ground, dtype=bool))
    if rows.size == 0:
        return out
    tiles = np.floor(p[rows, :2] / GROUND_TILE_M).astype(np.int64)
    _, tile = np.unique(tiles, axis=0, return_inverse=True)
    for k in range(int(tile.max()) + 1):
        idx = rows[tile.ravel() == k]
        if idx.size < GROUND_TILE_MIN:
            continue
        a = np.column_stack([p[idx, 0], p[idx, 1], np.ones(idx.size)])
        slope_x, slope_y, _ = np.linalg.lstsq(a, p[idx, 2], rcond=None)[0]
        normal = np.array([-slope_x, -slope_y, 1.0]) / math.hypot(slope_x, slope_y, 1.0)
        ray = p[idx] / np.linalg.norm(p[idx], axis=1, keepdims=True)
        out[idx] = np.abs(ray @ normal)
    return out


def _ground_plane(xyz: npt.NDArray[np.float32]) -> npt.NDArray[np.bool_]:
    """Points within 0.15 m of a least-squares ground plane (for unlabelled nuScenes)."""
    p = xyz.astype(np.float64)
    horiz = np.hypot(p[:, 0], p[:, 1])
    near = (horiz > 3.0) & (horiz < 40.0)
    z = p[near, 2]
    hist, edges = np.histogram(z, bins=np.arange(z.min(), z.max() + 0.1, 0.1))
    z0 = edges[int(np.argmax(hist))] + 0.05
    sel = near & (np.abs(p[:, 2] - z0) < 0.3)
    coef = np.zeros(3)
    for tol in (0.3, 0.15, 0.1):
        a = np.column_stack([p[sel, 0], p[sel, 1], np.ones(int(sel.sum()))])
        coef = np.linalg.lstsq(a, p[sel, 2], rcond=None)[0]
        res = np.abs(p[:, 2] - (coef[0] * p[:, 0] + coef[1] * p[:, 1] + coef[2]))
        sel = near & (res < tol)
    res = np.abs(p[:, 2] - (coef[0] * p[:, 0] + coef[1] * p[:, 1] + coef[2]))
    return (res < 0.15) & (horiz < 60.0)


# ----------------------------------------------------------------------------------------
# Scans: rotated copies, ground-only filtering, subsampling


@dataclass
class Scan:
    relpath: str
    label_relpath: str | None
    frame: int
    yaw_deg: float
    rows: npt.NDArray[np.int64]  # rows of the base frame, in file order
    xyz: npt.NDArray[np.float32]


def _rotate(xyz: npt.NDArray[np.float32], yaw_deg: float) -> npt.NDArray[np.float32]:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    p = xyz.astype(np.float64)
    out = np.column_stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]])
    return out.astype(np.float32)


def _ring_sorted(
    xyz: npt.NDArray[np.float32], ring: npt.NDArray[np.int64]
) -> npt.NDArray[np.int64]:
    """Row order keeping KITTI's ring blocks (top ring first) and sorting each by azimuth."""
    yaw = np.mod(np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0]), 2 * np.pi)
    return np.lexsort((yaw, -ring))


def _make_scans(
    base: str,
    frames: tuple[BaseFrame, ...],
    rng: np.random.Generator,
    ground_only: bool,
    max_points: int | None,
    sub_rng: np.random.Generator,
    copies: int,
) -> list[Scan]:
    n_frames = len(frames)
    profile = load_profile(PROFILES[base])
    scans = []
    for k in range(copies):
        for fi, fr in enumerate(frames):
            yaw = 0.0 if k == 0 else float(rng.uniform(0.0, 360.0))
            rows = np.arange(len(fr.xyz), dtype=np.int64)
            xyz = fr.xyz
            if k > 0:
                xyz = _rotate(fr.xyz, yaw)
                if base == "semantickitti":
                    rows = _ring_sorted(xyz, fr.ring)
                    xyz = xyz[rows]
                    if not np.array_equal(
                        rings_from_scan_order(xyz, profile.channels), fr.ring[rows]
                    ):
                        raise RuntimeError("rotated copy lost the scan-order rings")
            if ground_only:
                keep = fr.ground[rows]
                rows, xyz = rows[keep], xyz[keep]
            if max_points is not None and len(rows) > max_points:
                pick = np.sort(sub_rng.choice(len(rows), size=max_points, replace=False))
                rows, xyz = rows[pick], xyz[pick]
            if base == "semantickitti":
                stem = f"{k * n_frames + fi:06d}"
                rel = f"sequences/00/velodyne/{stem}.bin"
                lab = f"sequences/00/labels/{stem}.label"
            else:
                head, _, tail = fr.name.partition("__LIDAR_TOP__")
                stamp = int(tail.split(".")[0]) + (k * n_frames + fi) * NUSCENES_STEP_US
                rel = f"samples/LIDAR_TOP/{head}__LIDAR_TOP__{stamp}.pcd.bin"
                lab = None
            scans.append(Scan(rel, lab, fi, yaw, rows, np.ascontiguousarray(xyz)))
    return sorted(scans, key=lambda s: s.relpath)


# ----------------------------------------------------------------------------------------
# Geometry of the whole tree (all scans concatenated)


@dataclass
class Geom:
    """Per-point arrays over all scans of a tree, concatenated in scan order."""

    base: str
    enc: IntensityEncoding
    h: float
    n_rings: int
    labelled: bool
    scan: npt.NDArray[np.int64]
    n_scans: int
    R: npt.NDArray[np.float64]
    cos: npt.NDArray[np.float64]  # floored at COS_FLOOR
    ring: npt.NDArray[np.int64]
    cls: npt.NDArray[np.int64]
    obj: npt.NDArray[np.int64]
    edge: npt.NDArray[np.float64]
    az_deg: npt.NDArray[np.float64]
    x_a: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))  # B's source
    stored_a: npt.NDArray[np.float32] = field(default_factory=lambda: np.zeros(0, np.float32))

    @property
    def y0(self) -> npt.NDArray[np.float64]:
        return np.log(self.x_a + self.h)

    def __len__(self) -> int:
        return len(self.R)


def _geom(base: str, frames: tuple[BaseFrame, ...], scans: list[Scan]) -> Geom:
    profile = load_profile(PROFILES[base])
    parts: dict[str, list[Any]] = {
        k: [] for k in ("scan", "R", "cos", "ring", "cls", "obj", "edge", "az")
    }
    # Object ids are per scan, copies included: each copy stands in for another scene, so
    # its objects draw their own reflectance offsets. Shared draws would make the copies'
    # tiles, which the tool holds out as independent groups, repeat the same noise.
    obj_offset = np.cumsum([0] + [int(frames[s.frame].obj.max()) + 1 for s in scans])
    for si, s in enumerate(scans):
        fr = frames[s.frame]
        p = s.xyz.astype(np.float64)
        parts["scan"].append(np.full(len(p), si, dtype=np.int64))
        parts["R"].append(np.linalg.norm(p, axis=1))
        parts["cos"].append(np.clip(fr.cos[s.rows], COS_FLOOR, 1.0))
        parts["ring"].append(fr.ring[s.rows])
        cls = (
            (fr.labels[s.rows] & 0xFFFF).astype(np.int64)
            if fr.labels is not None
            else (np.full(len(p), -1, dtype=np.int64))
        )
        parts["cls"].append(cls)
        parts["obj"].append(fr.obj[s.rows] + obj_offset[si])
        parts["edge"].append(fr.edge[s.rows])
        parts["az"].append(np.mod(np.degrees(np.arctan2(p[:, 1], p[:, 0])), 360.0))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    return Geom(
        base=base,
        enc=profile.intensity,
        h=0.5 * profile.intensity.step,
        n_rings=profile.channels,
        labelled=frames[0].labels is not None,
        scan=cat["scan"],
        n_scans=len(scans),
        R=cat["R"],
        cos=cat["cos"],
        ring=cat["ring"],
        cls=cat["cls"],
        obj=cat["obj"],
        edge=cat["edge"],
        az_deg=cat["az"],
    )


def quantise(x: npt.ArrayLike, enc: IntensityEncoding) -> npt.NDArray[np.float32]:
    """Continuous stored-unit intensity -> the encoding's float32 levels (rounded, clipped)."""
    arr = np.nan_to_num(np.asarray(x, dtype=np.float64), nan=0.0, posinf=enc.max_value)
    return enc.from_reflectivity(np.clip(arr, 0.0, None) / enc.reflectivity_full_scale)


# ----------------------------------------------------------------------------------------
# Hidden effects


@dataclass
class Component:
    """One hidden effect: its truth entry and what it does to B."""

    effect: dict[str, Any]
    ranges: dict[str, list[float]]
    t: npt.NDArray[np.float64] | None = None  # term added to ln(I + h)
    survive: npt.NDArray[np.float64] | None = None  # P(return), (N,)
    encode: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None = None
    domain: npt.NDArray[np.bool_] | None = None  # points the RMS is taken over (None: all)
    banded: bool = True
    unidentifiable: list[str] = field(default_factory=list)

    def ln_term(self, g: Geom) -> npt.NDArray[np.float64]:
        if self.encode is not None:
            x = g.x_a
            return np.log(np.clip(self.encode(x), 0.0, None) + g.h) - np.log(x + g.h)
        return self.t if self.t is not None else np.zeros(len(g))


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _c1(rng: np.random.Generator, g: Geom) -> Component:
    if g.base == "nuscenes" and rng.uniform(0.0, 1.3) < 0.5:
        lo, hi = -2.0, -1.5
    else:
        lo, hi = 0.2, 1.0
    dn = _u(rng, lo, hi)
    return Component(_effect("C1", {"delta_n": dn}), {"delta_n": [lo, hi]}, t=-dn * np.log(g.R))


def _c5(rng: np.random.Generator, g: Geom) -> Component:
    a = _u(rng, 0.002, 0.03)
    return Component(
        _effect("C5", {"alpha_per_m": a}), {"alpha_per_m": [0.002, 0.03]}, t=-2.0 * a * g.R
    )


def _c2(rng: np.random.Generator, g: Geom) -> Component:
    r0, k = _u(rng, 2.0, 8.0), _u(rng, 2.0, 6.0)
    return Component(
        _effect("C2", {"r0_m": r0, "k": k}),
        {"r0_m": [2.0, 8.0], "k": [2.0, 6.0]},
        t=-np.log1p((r0 / g.R) ** k),
    )


def _c4_all(rng: np.random.Generator, g: Geom) -> Component:
    s = _u(rng, 0.05, 0.3)
    ln_g = rng.normal(0.0, s, g.n_rings)
    ln_g -= ln_g.mean()
    return Component(
        _effect("C4", {"ln_gain_by_ring": [float(v) for v in ln_g]}, info={"sigma_ln_gain": s}),
        {"ln_gain_by_ring": [-0.6, 0.6]},
        t=ln_g[g.ring],
    )


def case_k1(rng: np.random.Generator, g: Geom) -> list[Component]:
    return [_c1(rng, g)]


def case_k2(rng: np.random.Generator, g: Geom) -> list[Component]:
    return [_c5(rng, g)]


def case_k3(rng: np.random.Generator, g: Geom) -> list[Component]:
    return [_c2(rng, g)]


def case_k4(rng: np.random.Generator, g: Geom) -> list[Component]:
    if rng.uniform() < 0.5:
        p = _u(rng, 0.5, 2.0)
        return [
            Component(
                _effect("C3", {"p_extra": p - 1.0}, info={"model": "cos^p", "p": p}),
                {"p_extra": [-0.5, 1.0]},
                t=(p - 1.0) * np.log(g.cos),
            )
        ]
    sigma = _u(rng, 0.15, 0.5)
    s2 = sigma * sigma
    a, b = 1.0 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)
    t = np.log(a + b * (1.0 - g.cos**2) / g.cos)
    return [Component(_effect("C3", {}, info={"model": "oren_nayar", "sigma_rad": sigma}), {}, t=t)]


def case_k5(rng: np.random.Generator, g: Geom) -> list[Component]:
    return [_c4_all(rng, g)]


def case_k6(rng: np.random.Generator, g: Geom) -> list[Component]:
    counts = np.bincount(g.ring, minlength=g.n_rings)
    eligible = np.flatnonzero(counts >= 0.005 * len(g))
    n = int(rng.integers(1, 4))
    rings = np.sort(rng.choice(eligible, size=min(n, eligible.size), replace=False))
    ln_g = np.zeros(g.n_rings)
    ln_g[rings] = np.log(rng.uniform(0.6, 0.85, rings.size))
    centred = ln_g - ln_g.mean()
    return [
        Component(
            _effect(
                "C4",
                {"ln_gain_by_ring": [float(v) for v in centred]},
                rings=[int(r) for r in rings],
                info={"gain_by_affected_ring": [float(math.exp(v)) for v in ln_g[rings]]},
            ),
            {"ln_gain_by_ring": [math.log(0.6), 0.0]},
            t=ln_g[g.ring],
            domain=np.isin(g.ring, rings),
        )
    ]


def case_k7(rng: np.random.Generator, g: Geom) -> list[Component]:
    k_s, m = _u(rng, 0.5, 3.0), _u(rng, 20.0, 200.0)
    car = g.cls == CAR
    t = np.where(car, np.log1p(k_s * g.cos ** (m - 1.0)), 0.0)
    return [
        Component(
            _effect("C3s", {"k_s": k_s, "m": m}, classes=["car"]),
            {"k_s": [0.5, 3.0], "m": [20.0, 200.0]},
            t=t,
            domain=car,
        )
    ]


def case_k8(rng: np.random.Generator, g: Geom) -> list[Component]:
    gain = _u(rng, 5.0, 50.0)
    sign = g.cls == SIGN
    t = np.where(sign, math.log(gain) - np.log(g.cos), 0.0)
    return [
        Component(
            _effect("C3r", {"ln_gain": math.log(gain)}, classes=["traffic-sign"]),
            {"ln_gain": [math.log(5.0), math.log(50.0)]},
            t=t,
            domain=sign,
        )
    ]


def case_k9(rng: np.random.Generator, g: Geom) -> list[Component]:
    enc = g.enc
    fs, step = enc.reflectivity_full_scale, enc.step
    gamma = _u(rng, 0.6, 0.9)
    offset = float(np.round(_u(rng, 0.0, 4.0))) * step
    scale = enc.max_value / 255.0 if enc.kind == "unit" else 1.0
    lo, hi = 150.0 * scale, 230.0 * scale
    i_max = float(quantise(np.array([_u(rng, lo, hi)]), enc)[0])

    def encode(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        x = np.clip(x, 0.0, None)
        return np.minimum(fs * (x / fs) ** gamma + offset, i_max)

    return [
        Component(
            _effect("C9", {"gamma": gamma, "offset": offset, "i_max": i_max}),
            {"gamma": [0.6, 0.9], "offset": [0.0, 4.0 * step], "i_max": [lo, hi]},
            encode=encode,
        )
    ]


def _drop_fraction(mu: npt.NDArray[np.float64], ln_tau: float, s: float) -> float:
    return float(np.mean(ndtr(-(mu - ln_tau) / s)))


def _solve_ln_tau(mu: npt.NDArray[np.float64], s: float, target: float) -> float:
    lo, hi = float(mu.min()) - 10.0 * s, float(mu.max()) + 10.0 * s
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if _drop_fraction(mu, mid, s) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def case_k10(rng: np.random.Generator, g: Geom) -> list[Component]:
    s, target = _u(rng, 0.2, 1.0), _u(rng, 0.03, 0.15)
    mu = g.y0
    ln_tau = _solve_ln_tau(mu, s, target)
    ranges = {
        "ln_tau": sorted([_solve_ln_tau(mu, s, 0.03), _solve_ln_tau(mu, s, 0.15)]),
        "s": [0.2, 1.0],
    }
    survive = ndtr((mu - ln_tau) / s)
    return [
        Component(
            _effect(
                "D1",
                {"ln_tau": ln_tau, "s": s},
                info={"drop_fraction": float(1.0 - survive.mean())},
            ),
            ranges,
            survive=survive,
            banded=False,
        )
    ]


def case_k11(rng: np.random.Generator, g: Geom) -> list[Component]:
    f, theta_c = _u(rng, 0.3, 0.8), _u(rng, 60.0, 80.0)
    wet = np.isin(g.cls, (ROAD, SIDEWALK))
    t = np.where(wet, math.log(1.0 - f), 0.0)  # F(theta) ~ 0 off the specular direction
    survive = np.where(wet & (g.cos < math.cos(math.radians(theta_c))), 0.0, 1.0)
    return [
        Component(
            _effect(
                "C7",
                {"f": f, "theta_c_deg": theta_c},
                classes=["road", "sidewalk"],
                info={
                    "F": "0 (no specular return to a monostatic sensor off the normal)",
                    "dropped_fraction_of_wet": float(1.0 - survive[wet].mean()),
                },
            ),
            {"f": [0.3, 0.8], "theta_c_deg": [60.0, 80.0]},
            t=t,
            survive=survive,
            domain=wet,
        )
    ]


def case_k12(rng: np.random.Generator, g: Geom) -> list[Component]:
    return [_c5(rng, g), _c4_all(rng, g)]


def case_k13(rng: np.random.Generator, g: Geom) -> list[Component]:
    return [_c2(rng, g), _c1(rng, g)]


def case_k14(rng: np.random.Generator, g: Geom) -> list[Component]:
    return [Component(_effect("C3", {"p_extra": -1.0}), {"p_extra": [-1.0, 2.0]}, t=-np.log(g.cos))]


def case_k15(rng: np.random.Generator, g: Geom) -> list[Component]:
    start, width = _u(rng, 0.0, 360.0), _u(rng, 10.0, 40.0)
    a, drop = 1.0 - _u(rng, 0.5, 0.8), _u(rng, 0.05, 0.3)
    inside = np.mod(g.az_deg - start, 360.0) < width
    t = np.where(inside, math.log(1.0 - a), 0.0)
    survive = np.where(inside, 1.0 - drop, 1.0)
    params = {"start_deg": start, "width_deg": width, "a": a, "drop_fraction": drop}
    ranges = {
        "start_deg": [0.0, 360.0],
        "width_deg": [10.0, 40.0],
        "a": [0.2, 0.5],
        "drop_fraction": [0.05, 0.3],
    }
    return [Component(_effect("C11", params), ranges, t=t, survive=survive, domain=inside)]


def case_k16(rng: np.random.Generator, g: Geom) -> list[Component]:
    beta = _u(rng, 0.3, 1.0)
    mean_s = np.array([g.stored_a[g.scan == s].mean() for s in range(g.n_scans)], np.float64)
    ln_m = np.log(np.maximum(mean_s, g.h))
    term_s = -beta * (ln_m - ln_m.mean())
    return [
        Component(
            _effect("C10", {"beta": beta}, info={"ln_scan_mean": [float(v) for v in ln_m]}),
            {"beta": [0.3, 1.0]},
            t=term_s[g.scan],
        )
    ]


def case_k17(rng: np.random.Generator, g: Geom) -> list[Component]:
    a, e0 = _u(rng, 0.3, 0.7), _u(rng, 0.5, 1.5)
    t = np.log1p(-a * np.exp(-g.edge / e0))
    return [
        Component(
            _effect("C8", {"a": a, "e0_beams": e0}),
            {"a": [0.3, 0.7], "e0_beams": [0.5, 1.5]},
            t=t,
            domain=g.edge <= 2.0,
        )
    ]


def case_null(rng: np.random.Generator, g: Geom) -> list[Component]:
    return []


def case_k20(rng: np.random.Generator, g: Geom) -> list[Component]:
    s = _u(rng, 0.6, 1.5)
    veg = g.cls == VEGETATION
    name = class_materials(LABEL_SET)[VEGETATION][0]
    return [
        Component(
            _effect("C6", {f"ln_scale_{name}": math.log(s)}, classes=[name]),
            {f"ln_scale_{name}": [math.log(0.6), math.log(1.5)]},
            t=np.where(veg, math.log(s), 0.0),
            domain=veg,
        )
    ]


CASE_FUNCS: dict[str, Callable[[np.random.Generator, Geom], list[Component]]] = {
    "K1": case_k1,
    "K2": case_k2,
    "K3": case_k3,
    "K4": case_k4,
    "K5": case_k5,
    "K6": case_k6,
    "K7": case_k7,
    "K8": case_k8,
    "K9": case_k9,
    "K10": case_k10,
    "K11": case_k11,
    "K12": case_k12,
    "K13": case_k13,
    "K14": case_k14,
    "K15": case_k15,
    "K16": case_k16,
    "K17": case_k17,
    "K18": case_null,
    "K19": case_null,
    "K20": case_k20,
}


def hidden_rms(term: npt.NDArray[np.float64], domain: npt.NDArray[np.bool_] | None) -> float:
    """RMS of a hidden ln-term after removing its global mean (C0), over its domain."""
    centred = term - term.mean()
    if domain is not None:
        centred = centred[domain]
    return float(np.sqrt(np.mean(centred**2))) if centred.size else 0.0


@dataclass
class Draw:
    comps: list[Component]
    sigma_n: float
    sigma_obj: float
    hetero_b: float
    sizes: list[dict[str, Any]]
    tries: int
    in_band: bool


def _draw(case: str, mode: str, g: Geom, rng: np.random.Generator) -> Draw:
    first: Draw | None = None
    for attempt in range(1, MAX_TRIES + 1):
        sigma_n = _u(rng, *NOISE_SIGMA)
        sigma_obj = _u(rng, *OBJECT_SIGMA) if mode == "M2" else 0.0
        hetero_b = _u(rng, 0.5, 1.0) if case == "K19" else 0.0
        comps = CASE_FUNCS[case](rng, g)
        sigma = math.hypot(sigma_n, sigma_obj)
        sizes, ok = [], True
        for c in comps:
            rms = hidden_rms(c.ln_term(g), c.domain)
            ratio = rms / sigma
            inside = BAND[0] <= ratio <= BAND[1]
            sizes.append(
                {
                    "id": c.effect["id"],
                    "rms_ln": rms,
                    "sigma": sigma,
                    "ratio": ratio,
                    "banded": c.banded,
                    "in_band": inside,
                }
            )
            ok &= inside or not c.banded
        draw = Draw(comps, sigma_n, sigma_obj, hetero_b, sizes, attempt, ok)
        if ok:
            return draw
        if first is None:
            first = draw
    assert first is not None
    first.tries = MAX_TRIES
    return first


# ----------------------------------------------------------------------------------------
# Writing


def _write_tree(
    root: Path,
    base: str,
    scans: list[Scan],
    frames: tuple[BaseFrame, ...],
    intensity: npt.NDArray[np.float32],
    keep: npt.NDArray[np.bool_],
    scan_of: npt.NDArray[np.int64],
) -> int:
    """Write one tree; returns the number of points written."""
    if root.exists():
        shutil.rmtree(root)
    total = 0
    for si, s in enumerate(scans):
        sel = scan_of == si
        k = keep[sel]
        xyz = s.xyz[k]
        inten = intensity[sel][k].astype(np.float32)
        fr = frames[s.frame]
        if base == "semantickitti":
            pts = np.column_stack([xyz, inten]).astype("<f4")
        else:
            assert fr.ring_column is not None
            pts = np.column_stack([xyz, inten, fr.ring_column[s.rows][k]]).astype("<f4")
        path = root / s.relpath
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(np.ascontiguousarray(pts).tobytes())
        if s.label_relpath is not None and fr.labels is not None:
            lab = root / s.label_relpath
            lab.parent.mkdir(parents=True, exist_ok=True)
            lab.write_bytes(np.ascontiguousarray(fr.labels[s.rows][k]).astype("<u4").tobytes())
        total += int(k.sum())
    return total


def _clean(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float):
        return float(f"{value:.10g}")
    return value


def generate_case(
    case: str,
    base: str,
    seed: int,
    out_dir: Path,
    *,
    mode: str = "M2",
    max_points: int | None = None,
    noise_scale: float = 1.0,
    copies: int | None = None,
) -> None:
    """Write out_dir/{sim,real,oracle}/ and out_dir/truth.json for one case (see module doc).

    Args:
        case: "K1".."K20".
        base: "semantickitti" or "nuscenes".
        seed: any integer; (case, base, seed, mode, max_points) fixes every byte written.
        out_dir: folder to write into (created; existing sim/real/oracle are replaced).
        mode: "M1" (real -> real) or "M2" (simple sim -> real-like).
        max_points: at most this many points per scan (the same rows in every tree).
        noise_scale: multiplies the drawn noise and object spread when B is built (1 in the
            benchmark; 0 gives a noiseless B for tests). Parameters and the effect-size band
            use the drawn sigmas, so they do not depend on it.
        copies: scans per real frame, the original included (default COPIES[base]).

    Raises:
        ValueError: unknown case, base or mode, or a class case on an unlabelled base.
    """
    if case not in CASES:
        raise ValueError(f"unknown case {case!r}; expected one of K1..K20")
    _check_base(base)
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {MODES}")
    if case not in cases_for(base):
        raise ValueError(f"case {case} needs class labels; base {base} is unlabelled")
    if max_points is not None and max_points < 100:
        raise ValueError(f"max_points = {max_points}; expected >= 100 or None")
    copies = COPIES[base] if copies is None else copies
    if copies < 1:
        raise ValueError(f"copies = {copies}; expected >= 1")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = load_base(base)
    key = (case, base, seed, mode)
    scans = _make_scans(
        base,
        frames,
        _rng(*key, "rotation"),
        case == "K14",
        max_points,
        _rng(*key, max_points, "subsample"),
        copies,
    )
    g = _geom(base, frames, scans)
    enc, h = g.enc, g.h
    n = len(g)

    # A: the real intensities (M1) or the simple simulation (M2).
    scale = None
    if mode == "M1":
        real = np.concatenate([frames[s.frame].intensity[s.rows] for s in scans]).astype(np.float64)
        x_a = real
    else:
        if g.labelled:
            labels = np.concatenate([frames[s.frame].labels[s.rows] for s in scans])  # type: ignore[index]
            rho = reflectance_for_labels(labels, LABEL_SET).astype(np.float64)
        else:
            rho = np.full(n, 0.2)
        raw = rho * g.cos / g.R**2
        scale = min(
            M2_MEDIAN[base] / float(np.median(raw)),
            enc.max_value / float(np.quantile(raw, 1.0 - M2_MAX_SATURATED)),
        )
        x_a = raw * scale
    brightness = None
    if case == "K16":
        brightness = _rng(*key, "scene").normal(0.0, AGC_SCENE_SIGMA, g.n_scans)
        x_a = np.exp(np.log(x_a + h) + brightness[g.scan]) - h
        if mode == "M1":
            x_a = quantise(x_a, enc).astype(np.float64)
    stored_a = quantise(x_a, enc)
    g.x_a = np.clip(x_a, 0.0, None)
    g.stored_a = stored_a

    draw = _draw(case, mode, g, _rng(*key, "params"))
    t = np.zeros(n)
    survive = np.ones(n)
    encode = None
    for c in draw.comps:
        if c.t is not None:
            t += c.t
        if c.survive is not None:
            survive *= c.survive
        if c.encode is not None:
            encode = c.encode

    # A recording's overall level is set by its sensor's gain, which keeps typical returns
    # inside the encoding whatever the physics; the level is C0, the tool's to fit, and
    # §6.3 measures effect sizes after removing it. Left in, a steep range law (K13's mean
    # t of about -2.5) pushed half of B to the encoding's 0 and the case tested the
    # quantisation floor instead of its effects.
    t -= float(t.mean())

    # Oracle: the true transform, no noise, no object spread, no dropout.
    def finish(y: npt.NDArray[np.float64]) -> npt.NDArray[np.float32]:
        x = np.clip(np.exp(y) - h, 0.0, None)
        if encode is not None:
            x = encode(x)
        return quantise(x, enc)

    # From A as stored (what the tool reads), not from the unrounded x_A: rounding twice
    # moves low values by a step, and an oracle that had x_A held the rms ln distance of a
    # perfect correction at ~0.15 on KITTI (K5), which capped the recovery ratio of small
    # effects far below 1 whatever the tool did.
    y_or = np.log(g.stored_a.astype(np.float64) + h) + t
    oracle = finish(y_or)

    # B: the transform plus noise (and object spread in M2), then dropout.
    noise_rng = _rng(*key, "noise")
    sigma_pt = np.full(n, draw.sigma_n)
    r_med = float(np.median(g.R))
    if case == "K19":
        sigma_pt = np.minimum(draw.sigma_n * (g.R / r_med) ** draw.hetero_b, HETERO_SIGMA_CAP)
    eps = noise_rng.standard_normal(n) * sigma_pt * noise_scale
    obj_off = np.zeros(n)
    if mode == "M2":
        n_obj = int(g.obj.max()) + 1
        obj_off = (noise_rng.standard_normal(n_obj) * draw.sigma_obj * noise_scale)[g.obj]
    real_b = finish(y_or + obj_off + eps)
    drop_rng = _rng(*key, "dropout")
    random_drop = _u(drop_rng, *RANDOM_DROP) if mode == "M2" else 0.0
    u = drop_rng.random(n)
    keep = (u < survive) & (drop_rng.random(n) >= random_drop)

    # Parameters the data cannot inform.
    for c in draw.comps:
        if c.effect["id"] == "C3r":
            sat = oracle[c.domain] >= enc.max_value
            c.effect["info"] = {"saturated_fraction": float(sat.mean()) if sat.size else 0.0}
            if sat.size and sat.mean() > 0.5:
                c.unidentifiable.append("ln_gain")
        if c.effect["id"] == "C7" and c.domain is not None:
            # With every wet return beyond theta_c lost, no wet row shows the film's
            # darkening, and theta_c is only bounded by the smallest wet incidence.
            kept = float(np.mean(survive[c.domain] > 0)) if c.domain.any() else 0.0
            c.effect["info"]["kept_fraction_of_wet"] = kept
            if kept < 0.005:
                c.unidentifiable += ["f", "theta_c_deg"]
        if c.effect["id"] == "C9":
            reach = float(np.mean(oracle >= c.effect["params"]["i_max"]))
            c.effect["info"] = {"fraction_at_i_max": reach}
            if reach < 0.005:
                c.unidentifiable.append("i_max")

    all_rows = np.ones(n, dtype=bool)
    n_sim = _write_tree(out_dir / "sim", base, scans, frames, stored_a, all_rows, g.scan)
    n_real = _write_tree(out_dir / "real", base, scans, frames, real_b, keep, g.scan)
    _write_tree(out_dir / "oracle", base, scans, frames, oracle, all_rows, g.scan)

    effects = []
    for c in draw.comps:
        entry = dict(c.effect)
        entry["param_ranges"] = c.ranges
        if c.unidentifiable:
            entry["unidentifiable_params"] = c.unidentifiable
        effects.append(entry)
    param_ranges: dict[str, list[float]] = {}
    for c in draw.comps:
        param_ranges.update(c.ranges)
    noise: dict[str, Any] = {
        "kind": "heteroscedastic" if case == "K19" else "homoscedastic",
        "sigma_ln": draw.sigma_n,
        "object_sigma_ln": draw.sigma_obj,
    }
    if case == "K19":
        noise.update(
            {
                "form": "sigma_ln * (R / median_range_m)^range_power, capped at 1.0",
                "range_power": draw.hetero_b,
                "median_range_m": r_med,
            }
        )
    truth: dict[str, Any] = {
        "case": case,
        "description": CASE_DESCRIPTIONS[case],
        "base": base,
        "mode": mode,
        "seed": seed,
        "max_points": max_points,
        "copies": copies,
        "noise_scale": noise_scale,
        "effects": effects,
        "noise": noise,
        "accept_ambiguity": K14_ACCEPT if case == "K14" else [],
        "param_ranges": param_ranges,
        "effect_size": {
            "band": list(BAND),
            "tries": draw.tries,
            "in_band": draw.in_band,
            "effects": draw.sizes,
        },
        "random_dropout": random_drop,
        "drop_fraction": 1.0 - n_real / n_sim,
        "m2_scale": scale,
        "scene_brightness_ln": None if brightness is None else brightness.tolist(),
        "scans": [
            {
                "relpath": s.relpath,
                "frame": frames[s.frame].name,
                "yaw_deg": s.yaw_deg,
                "points": int(len(s.rows)),
            }
            for s in scans
        ],
        "points": {"sim": n_sim, "real": n_real},
        "ground_only": case == "K14",
    }
    (out_dir / "truth.json").write_text(json.dumps(_clean(truth), indent=2) + "\n")
