"""The beam table: one row per beam of a simulated and a real recording (docs/diagnose.md §5.1).

Everything `lads diagnose` fits or plots reads this table and nothing else, so trees of any
supported dataset are reduced to it once (`lads.diagnose.data.beams`).

Paired mode: one row per simulated beam (returned in the simulation) plus one row per real
return that no simulated beam claims (`ret_sim` False). A simulated beam whose real partner
is missing has `ret_real` False: it was dropped in reality. Beams that return in neither
cannot be seen in point clouds and have no row.

Unpaired mode: two tables of the same sensor, one per tree, each row one return of that tree;
only feature-conditional distributions are compared (never marginal histograms).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.diagnose.config import CONFIG


@dataclass(frozen=True, slots=True)
class SensorInfo:
    """What the fitter must know about the sensor that wrote both trees.

    Attributes:
        profile: sensor profile name (`lads profiles`), e.g. "hdl64e", "hdl32e".
        n_rings: laser channels.
        encoding_kind: "unit" (float in [0, 1)) or "byte" (0-255 integers).
        step: quantisation step of the stored intensity (0.01 or 1).
        max_value: largest storable intensity (0.99 or 255).
        full_scale: stored value that stands for reflectivity 1.
        calibrated: True when the sensor reports calibrated reflectivity (range divided out,
            e.g. HDL-32E v2 firmware), False for raw intensity (HDL-64E remission).
        has_ring_column: scans carry a ring column (else rings come from elevation).
        label_set: material label set of the labels (`lads.physics.materials`), or None.
    """

    profile: str
    n_rings: int
    encoding_kind: str
    step: float
    max_value: float
    full_scale: float
    calibrated: bool
    has_ring_column: bool
    label_set: str | None

    @property
    def half_step(self) -> float:
        """Half a quantisation step in stored units: the offset of ln(I + 1/2)."""
        return 0.5 * self.step


@dataclass(frozen=True, slots=True)
class BeamTable:
    """One row per beam; every array has the same length N and row order.

    Attributes:
        sensor: the sensor of both trees.
        scans: relative paths of the scans (the same in both trees when paired).
        class_names: class id -> name of the dataset's label set ({} when unlabelled).
        scan: (N,) int32 index into `scans`.
        group: (N,) int64 spatial group id, unique across scans: the scan and a 10 m x 10 m
            tile of the ground plane. Held-out splits and bootstraps resample groups, never
            points (docs/diagnose.md §2 item 4).
        ring: (N,) int16 laser channel, 0 = lowest beam.
        azimuth_deg: (N,) float32 azimuth in [0, 360), atan2(y, x) in degrees.
        elevation_deg: (N,) float32 beam elevation in degrees.
        range_m: (N,) float32 range in m (simulated range; real range for real-only rows).
        cos_incidence: (N,) float32 cosine of the incidence angle in [0, 1].
        normal_ok: (N,) bool the normal is well conditioned (image normal or planar kNN);
            False rows are excluded from incidence-dependent fits.
        class_id: (N,) int32 semantic class (dataset ids, instance bits removed); -1 unknown.
        is_ground: (N,) bool ground classes, or (unlabelled) within 0.25 m of the fitted
            ground plane with an upward normal.
        height_m: (N,) float32 height above the fitted ground plane in m.
        edge_beams: (N,) float32 distance in beams (azimuth steps along the ring) to the
            nearest depth edge (`edges.edge_distance`); capped at EDGE_CAP_BEAMS.
        edge_span_beams: (N,) float32 width in beams of the span that edge may lie in (a
            jump between returns g steps apart: g - 1; ~0 on a full scan, 0 when capped).
        i_sim: (N,) float32 simulated intensity in the stored units; NaN where not returned.
        i_real: (N,) float32 real intensity in the stored units; NaN where not returned.
        ret_sim: (N,) bool the simulation returned this beam.
        ret_real: (N,) bool reality returned this beam.
        sim_index: (N,) int64 row of the point in its simulated scan file, -1 if none.
        real_index: (N,) int64 row of the point in its real scan file, -1 if none.
    """

    sensor: SensorInfo
    scans: tuple[str, ...]
    class_names: dict[int, str]
    scan: npt.NDArray[np.int32]
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
    i_sim: npt.NDArray[np.float32]
    i_real: npt.NDArray[np.float32]
    ret_sim: npt.NDArray[np.bool_]
    ret_real: npt.NDArray[np.bool_]
    sim_index: npt.NDArray[np.int64]
    real_index: npt.NDArray[np.int64]
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.scan.shape[0])

    def take(self, rows: npt.ArrayLike) -> BeamTable:
        """The table restricted to `rows` (indices or a boolean mask), same metadata."""
        idx = np.asarray(rows)
        arrays = {f.name: getattr(self, f.name)[idx] for f in fields(self) if f.name in ROW_FIELDS}
        return replace(self, **arrays)


ROW_FIELDS: tuple[str, ...] = (
    "scan", "group", "ring", "azimuth_deg", "elevation_deg", "range_m", "cos_incidence",
    "normal_ok", "class_id", "is_ground", "height_m", "edge_beams", "edge_span_beams", "i_sim",
    "i_real", "ret_sim", "ret_real", "sim_index", "real_index",
)  # fmt: skip
EDGE_CAP_BEAMS = CONFIG.table.edge_cap_beams
GROUP_TILE_M = CONFIG.table.group_tile_m
