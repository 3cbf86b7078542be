"""One scan as another sensor would have recorded it (docs/transfer.md).

A window of source scans with their poses becomes a surfel scene (`surfels.scan_surfels`);
moving things come from the centre scan alone. The target sensor is ray-cast against it from
the centre scan's pose (`cast.cast_parts`); a beam returns where it meets a disk inside the
target's range limits and the return is strong enough for its detector. Range noise, labels,
intensity in the target's encoding and the source return behind every output point follow.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.errors import InputDataError
from lads.physics.materials import class_ids, class_roles, has_instance_bits
from lads.sensors.profile import SensorProfile
from lads.transfer.carve import free_space
from lads.transfer.cast import BeamHits, cast_parts
from lads.transfer.fov import covered_rings, hidden_beyond_view
from lads.transfer.surfels import (
    ALBEDO_MIN_COS,
    DEFAULT_SHAPE,
    DetectionFloor,
    Instances,
    Surfels,
    SurfelShape,
    scan_surfels,
)

F64 = npt.NDArray[np.float64]
# An instance whose centroid moved more than this between a neighbouring scan and the centre
# scan is moving: its surfels come from the centre scan only. Twice a car's centroid jitter
# from changing viewpoints, far below the 1 m it travels in 0.1 s at 36 km/h.
MOVING_INSTANCE_M = 0.5
# Width of the weighting of a surfel's reflectivity vote by how far the beam's view of it is
# from its own scan's, degrees (inf: every view the same; `cast.cast_parts`); chosen on
# validation streets by intensity error (benchmarks/sensor_transfer.py).
VIEW_SIGMA_DEG = 20.0
# (albedo, cos incidence, range m) -> bool: whether the target's detector sees the return.
Detector = Callable[[F64, F64, F64], npt.NDArray[np.bool_]]


@dataclass(frozen=True, slots=True)
class WindowScan:
    """One source scan of a window.

    Attributes:
        xyz: (N, 3) float32/64 coordinates in m, sensor frame.
        intensity: (N,) stored intensity in the source sensor's encoding.
        labels: (N,) stored labels or None.
        ring: (N,) channel per point or None.
        pose: (4, 4) float64 sensor -> world.
    """

    xyz: npt.NDArray[np.floating]
    intensity: npt.NDArray[np.floating]
    labels: npt.NDArray[np.generic] | None
    ring: npt.NDArray[np.generic] | None
    pose: F64


@dataclass(frozen=True, slots=True)
class TransferredScan:
    """The target sensor's scan, top channel first, each ring in azimuth order.

    Attributes:
        xyz: (M, 3) float32 coordinates in m, target frame.
        intensity: (M,) float32 in the target's encoding.
        labels: (M,) uint32 label of the surface hit (as stored by the source).
        ring: (M,) int64 target channel, 0 = lowest.
        column: (M,) int64 azimuth column of the beam.
        source_frame: (M,) int32 window index of the scan the hit surface came from.
        source_point: (M,) int64 row of that scan's return.
        range_m: (H, W) float64 range of every beam, 0 where it returned nothing.
    """

    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    labels: npt.NDArray[np.uint32]
    ring: npt.NDArray[np.int64]
    column: npt.NDArray[np.int64]
    source_frame: npt.NDArray[np.int32]
    source_point: npt.NDArray[np.int64]
    range_m: F64


def profile_detector(target: SensorProfile) -> Detector:
    """The target's median detection: albedo cos / R^2 at least its detection limit's
    reflectivity / range^2 (`detection` of the profile, docs/physics.md §9.7)."""
    limit = target.detection.power

    def detected(albedo: F64, cos: F64, range_m: F64) -> npt.NDArray[np.bool_]:
        return albedo * cos / (range_m * range_m) >= limit

    return detected


def transfer_scan(
    window: Sequence[WindowScan],
    centre: int,
    source: SensorProfile,
    target: SensorProfile,
    rng: np.random.Generator,
    *,
    label_set: str | None = None,
    azimuth_offset_rad: float = 0.0,
    target_from_source: F64 | None = None,
    detector: Detector | None = None,
    shape: SurfelShape = DEFAULT_SHAPE,
    floor: DetectionFloor | None = None,
) -> TransferredScan:
    """Scan `window[centre]` again with the `target` sensor.

    Args:
        window: neighbouring scans of one sequence with their poses, in time order.
        centre: index of the scan to transfer.
        source: the sensor of the window's scans; target: the sensor to scan with.
        rng: randomness of the target's range noise.
        label_set: the label set of the labels (moving classes, retro-reflectors), or None.
        azimuth_offset_rad: where the target's azimuth grid starts (its firing phase).
        target_from_source: (4, 4) pose of the target in the source sensor's frame
            (identity: mounted at the same place).
        detector: which returns the target detects; default `profile_detector(target)`.
        shape: how large the surfels are (`surfels.SurfelShape`).
        floor: the least albedo the source's detection of a return implies; default its
            profile's (`surfels.profile_floor`).

    Raises:
        InputDataError: `centre` outside the window, or a pose that is not (4, 4) and finite.
    """
    parts = [window_surfels(scan, source, label_set, shape, floor) for scan in window]
    return transfer_surfels(
        parts,
        [s.pose for s in window],
        centre,
        source,
        target,
        rng,
        label_set=label_set,
        azimuth_offset_rad=azimuth_offset_rad,
        target_from_source=target_from_source,
        detector=detector,
    )


def window_surfels(
    scan: WindowScan,
    source: SensorProfile,
    label_set: str | None,
    shape: SurfelShape = DEFAULT_SHAPE,
    floor: DetectionFloor | None = None,
) -> Surfels:
    """The surfels of one window scan in its sensor frame (compute once per scan: every
    window that holds the scan reuses them). Returns of the recording vehicle's own body
    (classes marked `ego` in materials.yaml) give none: the target sits on another vehicle.
    `floor`: the source's detection floor (default: its profile's, `profile_floor`)."""
    classes = None
    if label_set is not None and scan.labels is not None:
        classes = class_ids(scan.labels, label_set)
        roles = class_roles(label_set)
    refl = source.intensity.to_reflectivity(scan.intensity)
    retro = None if classes is None else np.isin(classes, sorted(roles.retroreflective))
    moving = None if classes is None else np.isin(classes, sorted(roles.moving))
    s = scan_surfels(
        scan.xyz,
        refl,
        source,
        labels=scan.labels,
        retro=retro,
        moving=moving,
        ring=scan.ring,
        shape=shape,
        floor=floor,
    )
    if classes is not None and roles.ego:
        s = s.take(~np.isin(classes[s.point], sorted(roles.ego)))
    return s.with_instances() if label_set is not None and has_instance_bits(label_set) else s


def transfer_surfels(
    parts: Sequence[Surfels],
    poses: Sequence[F64],
    centre: int,
    source: SensorProfile,
    target: SensorProfile,
    rng: np.random.Generator,
    *,
    label_set: str | None = None,
    azimuth_offset_rad: float = 0.0,
    target_from_source: F64 | None = None,
    detector: Detector | None = None,
    view_sigma_rad: float = math.radians(VIEW_SIGMA_DEG),
    carve: bool = True,
    footprint: bool = True,
) -> TransferredScan:
    """`transfer_scan` from each window scan's surfels (`window_surfels`) and poses; `carve`:
    drop hits in the centre scan's free space (`lads.transfer.carve`), with its footprint
    rule unless `footprint` is False."""
    if not 0 <= centre < len(parts) or len(poses) != len(parts):
        raise InputDataError(
            f"transfer: centre {centre} of a window of {len(parts)} scans and {len(poses)} "
            "poses; pass one pose per scan and a centre inside the window."
        )
    for k, pose in enumerate(poses):
        if np.shape(pose) != (4, 4) or not np.isfinite(pose).all():
            raise InputDataError(f"transfer: pose of window scan {k} is not a finite 4 x 4 matrix.")
    poses64 = [np.asarray(pose, dtype=np.float64) for pose in poses]
    bits = label_set is not None and has_instance_bits(label_set)
    kept = [np.flatnonzero(m) for m in _static(parts, poses64, centre, bits)]
    mount = np.eye(4) if target_from_source is None else np.asarray(target_from_source, float)
    to_target = np.linalg.inv(poses64[centre] @ mount)
    hits = cast_parts(
        parts,
        kept,
        [to_target @ pose for pose in poses64],
        np.radians(np.asarray(target.elevation_deg)),
        target.range_image_width,
        azimuth_offset_rad=azimuth_offset_rad,
        max_range_m=target.max_range_m,
        view_sigma_rad=view_sigma_rad,
        free=free_space(
            parts[centre].centre, source, mount, parts[centre].normal if footprint else None
        )
        if carve
        else None,
    )
    return _returns(
        hits,
        _Lookup(parts, kept),
        centre,
        source,
        target,
        rng,
        detector or profile_detector(target),
    )


@dataclass(frozen=True, slots=True)
class _Lookup:
    """Per-surfel facts of the gathered scene that only its beams' owners need."""

    parts: Sequence[Surfels]
    kept: list[npt.NDArray[np.int64]]

    def __call__(
        self, who: npt.NDArray[np.int64], *names: str
    ) -> tuple[npt.NDArray[np.int64], list[npt.NDArray[np.generic]]]:
        """The window scan each of the gathered surfels `who` (indices into the gathered
        scene) came from, and their fields `names`."""
        offsets = np.cumsum([0] + [len(k) for k in self.kept])
        part = np.searchsorted(offsets, who, side="right") - 1
        out = [np.empty(len(who), dtype=getattr(self.parts[0], n).dtype) for n in names]
        for p in range(len(self.parts)):
            mine = np.flatnonzero(part == p)
            if mine.size:
                rows = self.kept[p][who[mine] - offsets[p]]
                for values, n in zip(out, names, strict=True):
                    values[mine] = getattr(self.parts[p], n)[rows]
        return part, out


def _static(
    parts: Sequence[Surfels], poses: list[F64], centre: int, bits: bool
) -> list[npt.NDArray[np.bool_]]:
    """Per scan, the surfels a neighbouring scan may lend: not of a moving class, and not of
    an instance (id > 0) that is absent from the centre scan or whose world centroid moved
    more than MOVING_INSTANCE_M against it there."""
    ref = _world_instances(parts[centre], poses[centre]) if bits else None
    keep = []
    for k, part in enumerate(parts):
        ok = np.ones(len(part), dtype=bool)
        if k != centre:
            ok &= ~part.moving
        if k != centre and ref is not None:
            gone = _moved(*_world_instances(part, poses[k]), *ref)
            if gone.size:
                table = np.zeros(1 << 16, dtype=bool)
                table[gone] = True
                ok &= ~table[part.label >> np.uint32(16)]
        keep.append(ok)
    return keep


def _moved(
    ids: npt.NDArray[np.int64], xyz: F64, ref_ids: npt.NDArray[np.int64], ref_xyz: F64
) -> npt.NDArray[np.int64]:
    """The instance ids of a neighbouring scan (with world centroids xyz) that are absent
    from the centre scan (ref_ids, ref_xyz) or whose centroid moved more than
    MOVING_INSTANCE_M against it there."""
    if len(ref_ids) == 0:
        return ids
    at = np.minimum(np.searchsorted(ref_ids, ids), len(ref_ids) - 1)
    shift = np.linalg.norm(xyz - ref_xyz[at], axis=1)
    return ids[(ref_ids[at] != ids) | (shift > MOVING_INSTANCE_M)]


def _world_instances(part: Surfels, pose: F64) -> tuple[npt.NDArray[np.int64], F64]:
    """A scan's instance ids > 0, (L,) increasing, and (L, 3) their world centroids."""
    found = part.instances or Instances.of(part.label, part.centre)
    return found.ids, found.centre_m @ np.ascontiguousarray(pose[:3, :3].T) + pose[:3, 3]


def _owner_facts(owner: npt.NDArray[np.int64], lookup: _Lookup) -> dict[str, npt.NDArray]:
    """Per beam of the (H, W) `owner` image, flattened: the window scan of its surfel
    ("part", -1 without one: the source_frame of its return) and the surfel's moving, retro,
    label, point and least albedo."""
    names = ("moving", "retro", "label", "point", "least_albedo")
    beam = np.flatnonzero(owner.reshape(-1) >= 0)
    part, values = lookup(owner.reshape(-1)[beam], *names)
    facts = {"part": np.full(owner.size, -1, np.int64)}
    facts["part"][beam] = part
    for name, v in zip(names, values, strict=True):
        facts[name] = np.zeros(owner.size, v.dtype)
        facts[name][beam] = v
    return facts


def _returns(
    hits: BeamHits,
    lookup: _Lookup,
    centre: int,
    source: SensorProfile,
    target: SensorProfile,
    rng: np.random.Generator,
    detector: Detector,
) -> TransferredScan:
    """The returns the target records from its beams' hits, in its file order."""
    t = hits.range_m
    in_range = np.isfinite(t) & (t >= target.min_range_m) & (t <= target.max_range_m)
    owner = np.where(in_range, hits.owner, -1)
    facts = _owner_facts(owner, lookup)
    here = (facts["part"] == centre).reshape(t.shape)
    lent = (facts["part"] >= 0).reshape(t.shape) & ~here
    moving_here = here & facts["moving"].reshape(t.shape).astype(bool)
    covered = covered_rings(source.elevation_deg, target.elevation_deg)
    owner[hidden_beyond_view(t, moving_here, lent, covered)] = -1
    flat = np.flatnonzero(owner[::-1].reshape(-1) >= 0)  # top channel first, then azimuth
    rows, cols = np.divmod(flat, t.shape[1])
    ring = (t.shape[0] - 1 - rows).astype(np.int64)
    beam = ring * t.shape[1] + cols
    cos = np.where(facts["retro"][beam], 1.0, hits.cos_incidence[ring, cols])
    albedo = hits.reflectivity[ring, cols] / np.maximum(cos, ALBEDO_MIN_COS)
    # A surface the source detected was at least as bright as its detection implies, however
    # low its stored intensity (docs/transfer.md §2, "Returns").
    albedo = np.maximum(albedo, facts["least_albedo"][beam])
    rng_m = t[ring, cols]
    seen = detector(albedo, cos, rng_m)
    ring, cols, rng_m, beam = ring[seen], cols[seen], rng_m[seen], beam[seen]
    refl = hits.reflectivity[ring, cols]
    # The source's range noise is already in its returns: only the excess is added.
    extra = np.sqrt(max(target.range_accuracy_m**2 - source.range_accuracy_m**2, 0.0))
    if extra > 0:
        rng_m = rng_m + rng.normal(0.0, extra, rng_m.size)
    d = hits.directions()[ring, cols]
    image = np.zeros_like(t)
    image[ring, cols] = rng_m
    return TransferredScan(
        xyz=(d * rng_m[:, None]).astype(np.float32),
        intensity=target.intensity.from_reflectivity(refl),
        labels=facts["label"][beam].astype(np.uint32),
        ring=ring,
        column=cols.astype(np.int64),
        source_frame=facts["part"][beam].astype(np.int32),
        source_point=facts["point"][beam].astype(np.int64),
        range_m=image,
    )
