"""Reduce a simulated and a real tree to beam tables (docs/diagnose.md §5.1).

Every feature is computed per scan on each tree's own point cloud (vectorised numpy, one
range image per cloud for the normals, edge distances along the rings: `edges.py`). Paired
mode associates each simulated return with the nearest unclaimed real return within
`max_pair_distance_m`: a simulated beam without a partner was dropped in reality, a real
return without one is extra. Unpaired mode keeps one table per tree. Returns nearer than
the sensor profile's `min_range_m` are dropped in both modes, in paired mode together with
their partners (`lads.diagnose.data.minrange`).

Geometry features of a row come from its simulated point, or from its real point for
real-only rows. When only the real scan is labelled, paired rows take their class (and
ground flag) from the real partner, since a class is a property of the surface, not of
the simulation.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from tqdm.auto import tqdm

from lads.diagnose.config import CONFIG
from lads.diagnose.data.edges import edge_distance
from lads.diagnose.data.ground_normals import local_ground_cos
from lads.diagnose.data.minrange import beyond_min_range, pairs_beyond_min_range
from lads.diagnose.data.pairing import pair_points
from lads.diagnose.data.table import EDGE_CAP_BEAMS, GROUP_TILE_M, ROW_FIELDS, BeamTable
from lads.diagnose.data.trees import Scan, Tree, TreePair
from lads.errors import DiagnoseError, InputDataError
from lads.physics.materials import class_materials, class_roles
from lads.physics.modalities import IncidenceSource, incidence
from lads.physics.projection import project
from lads.sensors.measure import rings_from_scan_order
from lads.sensors.profile import SensorProfile

GROUND_RADIUS_M = CONFIG.table.ground_radius_m
GROUND_SEED_PERCENTILE = CONFIG.table.ground_seed_percentile
# Refits keep points ever closer to the plane: the first band lets a tilted seed find the
# ground, the narrower ones stop wall bases and kerbs from tilting the plane.
GROUND_INLIER_M = CONFIG.table.ground_inlier_m
GROUND_BAND_M = CONFIG.table.ground_band_m
GROUND_MAX_TILT_DEG = CONFIG.table.ground_max_tilt_deg
GROUND_MIN_POINTS = CONFIG.table.ground_min_points
SCAN_GROUP_STRIDE = 1_000_000
_TILE_OFFSET = 500  # tiles -500..499 (+-5 km at 10 m tiles) map to 0..999 per axis
_TILE_BASE = 1000

_DTYPES: dict[str, type] = {
    "scan": np.int32,
    "group": np.int64,
    "ring": np.int16,
    "azimuth_deg": np.float32,
    "elevation_deg": np.float32,
    "range_m": np.float32,
    "cos_incidence": np.float32,
    "normal_ok": np.bool_,
    "class_id": np.int32,
    "is_ground": np.bool_,
    "height_m": np.float32,
    "edge_beams": np.float32,
    "edge_span_beams": np.float32,
    "i_sim": np.float32,
    "i_real": np.float32,
    "ret_sim": np.bool_,
    "ret_real": np.bool_,
    "sim_index": np.int64,
    "real_index": np.int64,
}
_FEATURES = (
    "group", "ring", "azimuth_deg", "elevation_deg", "range_m", "cos_incidence", "normal_ok",
    "class_id", "is_ground", "height_m", "edge_beams", "edge_span_beams",
)  # fmt: skip
Rows = dict[str, npt.NDArray[Any]]


@dataclass(frozen=True, slots=True)
class CloudFeatures:
    """Per-point features of one scan's cloud; every array (N,), dtypes as in `BeamTable`.

    Attributes:
        group: int64 scan index * SCAN_GROUP_STRIDE + ground tile id.
        ring: int16 laser channel. azimuth_deg, elevation_deg, range_m: float32.
        cos_incidence: float32 in [0, 1]. normal_ok: bool, normal not a frame-median fallback.
        class_id: int32, -1 unlabelled. is_ground: bool. height_m: float32 above the ground.
        edge_beams: float32 beams (azimuth steps) to the nearest depth edge of the ring, capped.
        edge_span_beams: float32 width in beams of the span that edge may lie in.
    """

    group: npt.NDArray[np.int64]
    ring: npt.NDArray[np.int16]
    azimuth_deg: npt.NDArray[np.float32]
    elevation_deg: npt.NDArray[np.float32]
    range_m: npt.NDArray[np.float32]
    cos_incidence: npt.NDArray[np.float32]
    normal_ok: npt.NDArray[np.bool_]
    class_id: npt.NDArray[np.int32]
    is_ground: npt.NDArray[np.bool_]
    height_m: npt.NDArray[np.float32]
    edge_beams: npt.NDArray[np.float32]
    edge_span_beams: npt.NDArray[np.float32]

    def rows(self, idx: npt.NDArray[np.int64]) -> Rows:
        """The features of points `idx` as row arrays (copies)."""
        return {name: getattr(self, name)[idx] for name in _FEATURES}


def paired_table(
    pair: TreePair, *, max_pair_distance_m: float = 0.15, progress: bool = False
) -> BeamTable:
    """One row per simulated return plus one per real return no simulated return claims.

    Args:
        pair: trees opened with `paired=True` (same relpaths).
        max_pair_distance_m: largest sim-real distance of an associated pair, m.
        progress: show a tqdm bar over scans.

    Returns:
        BeamTable with scans = pair.sim_scans; per scan the simulated rows in file order,
        then the real-only rows in file order; returns nearer than the profile's
        min_range_m and their partners left out. meta: mode "paired", max_pair_distance_m,
        min_range_m.

    Raises:
        DiagnoseError: the pair is unpaired or a scan cannot be read (see `TreePair`).
    """
    if not pair.paired:
        raise DiagnoseError(
            f"{pair.sim_root} vs {pair.real_root}: the trees were opened unpaired; open them "
            "with paired=True (same relpaths) for a paired table, or use unpaired_tables."
        )
    if not max_pair_distance_m > 0:
        raise DiagnoseError(f"max_pair_distance_m = {max_pair_distance_m}; expected > 0 m.")
    parts = []
    for i, relpath in enumerate(_bar(pair.sim_scans, progress, "paired beam table")):
        sim, real = pair.read_scan("sim", relpath), pair.read_scan("real", relpath)
        parts.append(_paired_rows(pair, i, sim, real, max_pair_distance_m))
    meta = {
        "mode": "paired",
        "max_pair_distance_m": float(max_pair_distance_m),
        "min_range_m": pair.profile.min_range_m,
    }
    return _table(pair, pair.sim_scans, parts, meta)


def unpaired_tables(pair: TreePair, *, progress: bool = False) -> tuple[BeamTable, BeamTable]:
    """One table per tree, one row per return beyond the profile's min_range_m: (sim, real).

    The sim table has ret_sim True, ret_real False, i_real NaN, real_index -1; the real table
    the opposite. scans are pair.sim_scans and pair.real_scans. meta: mode "unpaired", tree,
    min_range_m.
    """
    tables = []
    trees: tuple[tuple[Tree, tuple[str, ...]], ...] = (
        ("sim", pair.sim_scans),
        ("real", pair.real_scans),
    )
    for tree, scans in trees:
        parts = []
        for i, relpath in enumerate(_bar(scans, progress, f"{tree} beam table")):
            scan = _ringed(pair.read_scan(tree, relpath), pair.profile)
            scan = beyond_min_range(scan, pair.profile.min_range_m)
            feats = cloud_features(scan, pair.profile, pair.sensor.label_set, i)
            parts.append(_own_rows(i, scan, feats, tree, np.arange(len(scan))))
        meta = {"mode": "unpaired", "tree": tree, "min_range_m": pair.profile.min_range_m}
        tables.append(_table(pair, scans, parts, meta))
    return tables[0], tables[1]


def _rings(xyz: npt.NDArray[np.float64], profile: SensorProfile) -> npt.NDArray[np.int64]:
    """Rings of a file without a ring column: its scan order when it is stored ring by ring
    (KITTI: the nearest profile elevation matches the true laser for only about half of the
    points, because the HDL-64E's lasers are not on the nominal elevations), else the
    nearest profile elevation."""
    try:
        return rings_from_scan_order(xyz, profile.channels)
    except InputDataError:
        return profile.channel_of(xyz)


def _ringed(scan: Scan, profile: SensorProfile) -> Scan:
    """`scan` with a ring for every point: its ring column, else recovered from the file.

    Runs before any point is dropped: scan-order recovery (`_rings`) reads the whole file in
    its stored order, and a cloud thinned by the minimum range filter is not that any more.
    """
    if scan.ring is not None or len(scan) == 0:
        return scan
    return replace(scan, ring=_rings(scan.xyz, profile).astype(np.int16))


def cloud_features(
    scan: Scan, profile: SensorProfile, label_set: str | None, scan_index: int
) -> CloudFeatures:
    """Features of every point of `scan` (see `CloudFeatures`), computed on this cloud alone.

    Rings come from the ring column, else from the profile's elevations; incidence from the
    range image normal (`lads.physics.modalities.incidence`), on the ground from local ground
    planes (`ground_normals.local_ground_cos`). Labelled scans (label_set not
    None and labels present) are ground by class and fit their ground plane on those classes;
    unlabelled ones are ground within GROUND_BAND_M of a robust plane fit.
    """
    n = len(scan)
    if n == 0:
        return _empty_features()
    xyz = scan.xyz
    ring = scan.ring.astype(np.int64) if scan.ring is not None else _rings(xyz, profile)
    image = project(xyz, profile, channel=ring)
    edge_beams, edge_span = edge_distance(xyz, ring, cap=EDGE_CAP_BEAMS)
    inc = incidence(xyz, profile, image=image)
    horizontal_m = np.hypot(xyz[:, 0], xyz[:, 1])
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])).astype(np.float32) % np.float32(360)
    azimuth[azimuth >= 360] = 0  # -tiny % 360 rounds to 360 in float32
    class_id = np.full(n, -1, dtype=np.int32)
    ground_class = None
    if label_set is not None and scan.labels is not None:
        class_id = scan.labels.astype(np.int32)
        # Road-like classes and terrain (materials.yaml `ground` and `flat`).
        level = sorted(class_roles(label_set).level_ground)
        ground_class = np.isin(scan.labels, level)
    height = plane_height(xyz, fit_ground_plane(xyz, ground_class))
    is_ground = ground_class if ground_class is not None else np.abs(height) < GROUND_BAND_M
    cos = inc.cos.astype(np.float32)
    normal_ok = inc.source != IncidenceSource.MEDIAN
    # The ground's image normals are ill-conditioned at range (ground_normals.py).
    plane_cos, plane_ok = local_ground_cos(np.asarray(xyz, dtype=np.float64), is_ground)
    cos[plane_ok] = plane_cos[plane_ok]
    normal_ok = normal_ok | plane_ok
    return CloudFeatures(
        group=scan_index * SCAN_GROUP_STRIDE + tile_ids(xyz),
        ring=ring.astype(np.int16),
        azimuth_deg=azimuth,
        elevation_deg=np.degrees(np.arctan2(xyz[:, 2], horizontal_m)).astype(np.float32),
        range_m=scan.range_m().astype(np.float32),
        cos_incidence=cos,
        normal_ok=normal_ok,
        class_id=class_id,
        is_ground=is_ground,
        height_m=height.astype(np.float32),
        edge_beams=edge_beams,
        edge_span_beams=edge_span,
    )


def fit_ground_plane(
    xyz: npt.NDArray[np.float64], ground_class: npt.NDArray[np.bool_] | None = None
) -> tuple[float, float, float]:
    """Robust ground plane z = a x + b y + c (a, b unitless, c in m) of one scan.

    Points within GROUND_RADIUS_M horizontally are used: the ground-class points when
    `ground_class` (N,) bool marks at least GROUND_MIN_POINTS of them, else all, seeded by
    those below the GROUND_SEED_PERCENTILE-th percentile of z. Least-squares refits follow,
    each on the points within the next band of GROUND_INLIER_M (m) of the previous plane.
    A plane tilted more than GROUND_MAX_TILT_DEG is replaced by the level plane through the
    seed's median z.

    Args:
        xyz: (N, 3) float64 coordinates in m, sensor frame.
        ground_class: optional (N,) bool labelled ground points.
    """
    near = np.hypot(xyz[:, 0], xyz[:, 1]) <= GROUND_RADIUS_M
    if ground_class is not None and np.count_nonzero(near & ground_class) >= GROUND_MIN_POINTS:
        pool = near & ground_class
        seed = pool
    else:
        pool = near if np.count_nonzero(near) >= 3 else np.ones(len(xyz), bool)
        if not pool.any():
            return 0.0, 0.0, 0.0
        seed = pool & (xyz[:, 2] <= np.percentile(xyz[pool, 2], GROUND_SEED_PERCENTILE))
    if np.count_nonzero(seed) < 3:
        return 0.0, 0.0, float(np.median(xyz[pool, 2]))
    coef = _lstsq_plane(xyz[seed])
    for band_m in GROUND_INLIER_M:
        inliers = pool & (np.abs(xyz[:, 2] - _plane_z(xyz, coef)) < band_m)
        if np.count_nonzero(inliers) < 3:
            break
        coef = _lstsq_plane(xyz[inliers])
    if math.hypot(coef[0], coef[1]) > math.tan(math.radians(GROUND_MAX_TILT_DEG)):
        return 0.0, 0.0, float(np.median(xyz[seed, 2]))
    return coef


def plane_height(
    xyz: npt.NDArray[np.float64], plane: tuple[float, float, float]
) -> npt.NDArray[np.float64]:
    """(N,) float64 signed distance in m of each point above the plane z = a x + b y + c."""
    a, b, _ = plane
    return (xyz[:, 2] - _plane_z(xyz, plane)) / math.sqrt(1.0 + a * a + b * b)


def tile_ids(xyz: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """(N,) int64 id in [0, SCAN_GROUP_STRIDE) of the GROUP_TILE_M square holding each point."""
    tiles = np.floor(xyz[:, :2] / GROUP_TILE_M)
    tiles = np.clip(tiles, -_TILE_OFFSET, _TILE_BASE - _TILE_OFFSET - 1).astype(np.int64)
    tiles += _TILE_OFFSET
    ids: npt.NDArray[np.int64] = tiles[:, 0] * _TILE_BASE + tiles[:, 1]
    return ids


def _paired_rows(pair: TreePair, i: int, sim: Scan, real: Scan, max_d: float) -> Rows:
    label_set = pair.sensor.label_set
    sim, real = _ringed(sim, pair.profile), _ringed(real, pair.profile)
    # Associate the whole clouds, then drop near points with their partners, so neither tree
    # keeps half of a pair that straddles the minimum range.
    partner = pair_points(sim.xyz, real.xyz, max_d)
    sim, real, partner = pairs_beyond_min_range(sim, real, partner, pair.profile.min_range_m)
    fs = cloud_features(sim, pair.profile, label_set, i)
    paired = partner >= 0
    mate = partner[paired]
    claimed = np.zeros(len(real), dtype=bool)
    claimed[mate] = True
    real_labels = sim.labels is None and real.labels is not None and label_set is not None
    # The real cloud's own features describe only its unpaired returns (and lend labels to
    # an unlabelled simulation); a real tree that the simulation covers point for point
    # needs none, and computing them was a third of the table's time.
    fr = _empty_features()
    if real_labels or not claimed.all():
        fr = cloud_features(real, pair.profile, label_set, i)
    sim_rows = _own_rows(i, sim, fs, "sim", np.arange(len(sim)))
    sim_rows["ret_real"] = paired
    sim_rows["i_real"][paired] = real.intensity[mate]
    sim_rows["real_index"][paired] = real.index[mate]
    if real_labels:
        sim_rows["class_id"][paired] = fr.class_id[mate]
        sim_rows["is_ground"][paired] = fr.is_ground[mate]
    real_rows = _own_rows(i, real, fr, "real", np.flatnonzero(~claimed))
    return {name: np.concatenate([sim_rows[name], real_rows[name]]) for name in sim_rows}


def _own_rows(i: int, scan: Scan, feats: CloudFeatures, tree: str, idx: npt.NDArray[Any]) -> Rows:
    """Rows of points `idx` of one tree's scan as returns of that tree alone."""
    n = idx.size
    missing = np.full(n, np.nan, np.float32)
    none = np.full(n, -1, np.int64)
    rows = feats.rows(idx)
    is_sim = tree == "sim"
    rows.update(
        scan=np.full(n, i, np.int32),
        i_sim=scan.intensity[idx] if is_sim else missing,
        i_real=missing.copy() if is_sim else scan.intensity[idx],
        ret_sim=np.full(n, is_sim),
        ret_real=np.full(n, not is_sim),
        sim_index=scan.index[idx] if is_sim else none,
        real_index=none.copy() if is_sim else scan.index[idx],
    )
    return rows


def _table(
    pair: TreePair, scans: tuple[str, ...], parts: list[Rows], meta: dict[str, Any]
) -> BeamTable:
    columns: Rows = {
        name: np.concatenate([p[name] for p in parts]).astype(_DTYPES[name], copy=False)
        if parts
        else np.zeros(0, _DTYPES[name])
        for name in ROW_FIELDS
    }
    label_set = pair.sensor.label_set
    names = {} if label_set is None else {k: v[0] for k, v in class_materials(label_set).items()}
    return BeamTable(sensor=pair.sensor, scans=scans, class_names=names, meta=meta, **columns)


def _empty_features() -> CloudFeatures:
    return CloudFeatures(**{name: np.zeros(0, _DTYPES[name]) for name in _FEATURES})


def _plane_z(
    xyz: npt.NDArray[np.float64], plane: tuple[float, float, float]
) -> npt.NDArray[np.float64]:
    a, b, c = plane
    return a * xyz[:, 0] + b * xyz[:, 1] + c


def _lstsq_plane(points: npt.NDArray[np.float64]) -> tuple[float, float, float]:
    design = np.column_stack([points[:, 0], points[:, 1], np.ones(len(points))])
    coef = np.linalg.lstsq(design, points[:, 2], rcond=None)[0]
    return float(coef[0]), float(coef[1]), float(coef[2])


def _bar(scans: Iterable[str], progress: bool, desc: str) -> Iterable[str]:
    bar: Iterable[str] = tqdm(scans, desc=desc, unit="scan", disable=None if progress else True)
    return bar
