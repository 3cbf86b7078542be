"""Ray-cast the procedural street frame by frame: points, labels, intensities and poses."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.physics.materials import reflectance_for_labels
from lads.sensors.profile import SensorProfile, load_profile
from lads.synth import geometry as geo
from lads.synth.parts import (
    RETROREFLECTIVE_PARTS,
    RHO_FACTOR_OF_PART,
    SEMANTICKITTI_OF_PART,
)
from lads.synth.scene import (
    CURB_HEIGHT_M,
    FRAME_PERIOD_S,
    ROAD_HALF_WIDTH_M,
    Scene,
    build_scene,
    ego_pose,
)

TEXTURE_SIGMA = 0.12  # log-normal spread of reflectivity per point (surface texture)
RANGE_NOISE_FRACTION = 0.75  # range noise sigma / profile.range_accuracy_m (1.5 cm for 2 cm)
# Detection limit: a return is kept if rho / R^2 >= DETECTED_RHO / max_range^2, i.e. an 80 %
# target is seen out to the profile's max range. For the HDL-64E (120 m) this puts 10 %
# pavement at 42 m, near its datasheet's "~50 m for 10 % pavement" (hdl64e.yaml sources).
DETECTED_RHO = 0.8


@dataclass(frozen=True, slots=True)
class SynthFrame:
    """One synthetic sweep, points in KITTI file order (ring by ring, top channel first,
    each ring in azimuth order from 0 to 2 pi).

    Attributes:
        xyz: (N, 3) float32 point coordinates in the sensor frame, m.
        intensity: (N,) float32 in the profile's intensity encoding (exactly on its grid).
        labels: (N,) uint32, SemanticKITTI raw id in the low 16 bits, instance id (cars and
            people, consistent across frames) in the high 16 bits.
        ring: (N,) int64 channel, 0 = lowest beam.
        pose: (4, 4) float64 sensor -> world transform.
        time_s: seconds since the first frame (10 Hz).
        reflectivity: (N,) float32 continuous physical intensity rho * cos(incidence) *
            texture, unitless, before encoding (what the Voxelscape layout stores).
        part: (N,) uint8 generator part code (lads.synth.parts.Part), finer than any label
            set (e.g. curb vs sidewalk, kid vs adult).
    """

    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    labels: npt.NDArray[np.uint32]
    ring: npt.NDArray[np.int64]
    pose: npt.NDArray[np.float64]
    time_s: float
    reflectivity: npt.NDArray[np.float32]
    part: npt.NDArray[np.uint8]


def synth_frames(
    profile: SensorProfile | str,
    *,
    frames: int,
    seed: int,
    azimuth_bins: int | None = None,
) -> Iterator[SynthFrame]:
    """Generate `frames` consecutive sweeps of the seeded street (no I/O).

    Args:
        profile: sensor profile (or its name): channels, elevations, range limits, intensity
            encoding and range accuracy.
        frames: number of sweeps, >= 1, at 10 Hz.
        seed: non-negative; the same seed gives identical frames, and the first k frames of
            a longer sequence equal a k-frame sequence.
        azimuth_bins: beams per channel; default `profile.range_image_width`.

    Yields:
        SynthFrame per sweep.

    Raises:
        ConfigError: frames < 1, seed < 0 or azimuth_bins < 4.
        SensorProfileError: unknown profile name.
    """
    if isinstance(profile, str):
        profile = load_profile(profile)
    columns = profile.range_image_width if azimuth_bins is None else int(azimuth_bins)
    if int(frames) < 1 or int(seed) < 0 or columns < 4:
        raise ConfigError(
            f"synthetic frames: frames={frames}, seed={seed}, azimuth_bins={azimuth_bins}; "
            "need frames >= 1, seed >= 0 and azimuth_bins >= 4 (or None for the profile's "
            "range_image_width)."
        )
    scene = build_scene(int(seed), (int(frames) - 1) * FRAME_PERIOD_S)
    for k in range(int(frames)):
        yield _frame(scene, profile, columns, int(seed), k)


def synth_frame(
    profile: SensorProfile | str,
    *,
    frames: int,
    seed: int,
    index: int,
    azimuth_bins: int | None = None,
) -> SynthFrame:
    """Frame `index` (0-based) of the `frames`-sweep sequence `synth_frames` would yield,
    computed on its own so that frames can be made in parallel.

    Raises:
        ConfigError: index outside [0, frames), or the arguments `synth_frames` refuses.
    """
    if not 0 <= int(index) < int(frames):
        raise ConfigError(f"synthetic frame index {index}: expected 0 <= index < {frames}.")
    if isinstance(profile, str):
        profile = load_profile(profile)
    columns = profile.range_image_width if azimuth_bins is None else int(azimuth_bins)
    if int(seed) < 0 or columns < 4:
        raise ConfigError(f"synthetic frames: seed={seed}, azimuth_bins={azimuth_bins}.")
    scene = build_scene(int(seed), (int(frames) - 1) * FRAME_PERIOD_S)
    return _frame(scene, profile, columns, int(seed), int(index))


def _cast_ground(
    beams: geo.Beams, ego_y: float, ego_z: float
) -> tuple[geo.F64, npt.NDArray[np.int32]]:
    """Road plane (z = 0), raised plane beyond the curbs (z = CURB_HEIGHT_M), curb faces."""
    with np.errstate(invalid="ignore", over="ignore"):
        inv_dz, inv_dy = beams.inv[2], beams.inv[1]
        t_road = -ego_z * inv_dz
        on_road = np.abs(ego_y + t_road * beams.dy) < ROAD_HALF_WIDTH_M
        t_curb = (np.copysign(ROAD_HALF_WIDTH_M, beams.dy) - ego_y) * inv_dy
        curb = ~on_road & (ego_z + t_curb * beams.dz <= CURB_HEIGHT_M)
        t_raised = (CURB_HEIGHT_M - ego_z) * inv_dz
    t = np.where(on_road, t_road, np.where(curb, t_curb, t_raised))
    t[beams.dz >= 0.0] = np.inf
    prim = np.where(curb, np.int32(geo.CURB_FACE), np.int32(geo.GROUND_PLANE))
    return t, prim.astype(np.int32)


def _frame(scene: Scene, profile: SensorProfile, columns: int, seed: int, k: int) -> SynthFrame:
    time_s = k * FRAME_PERIOD_S
    pose = ego_pose(seed, time_s)
    rng = np.random.default_rng([seed, 5, k])
    step = 2.0 * math.pi / columns
    offset = rng.uniform(-0.5, 0.5) * step  # sensor azimuths stay in [0, 2 pi)
    yaw = math.atan2(pose[1, 0], pose[0, 0])
    elevation = np.radians(np.asarray(profile.elevation_deg, dtype=np.float64))
    beams = geo.Beams.make(elevation, columns, yaw + offset)
    t_hit, prim = _cast_ground(beams, pose[1, 3], pose[2, 3])
    params, bbox = scene.prims.at(time_s, pose[:3, 3])
    geo.cast_primitives(beams, params, bbox, scene.prims.kind, t_hit, prim, profile.max_range_m)
    ring, d, t, pid = _in_file_order(beams, t_hit, prim, profile)
    point = d * t[:, None]  # world-aligned, relative to the sensor

    part, inst, rho_scale = _point_parts(scene, pid, point, pose)
    sem = SEMANTICKITTI_OF_PART[part]
    rho = reflectance_for_labels(sem, "semantickitti") * RHO_FACTOR_OF_PART[part] * rho_scale
    normal = geo.normals(point, pid, params, scene.prims.kind)
    cos_inc = np.clip(np.abs(np.einsum("ij,ij->i", normal, d)), 0.0, 1.0)
    cos_inc[np.isin(part, RETROREFLECTIVE_PARTS)] = 1.0
    texture = rng.lognormal(0.0, TEXTURE_SIGMA, size=t.size)
    # No 1/R^2: KITTI remission is (approximately) range-compensated, and LISA's convention
    # stores rho * cos(incidence); only detection depends on range (below).
    reflectivity = rho * cos_inc * texture
    seen = rho * texture / (t * t) >= detection_limit(profile)
    sigma = RANGE_NOISE_FRACTION * profile.range_accuracy_m
    range_m = np.clip(t + rng.normal(0.0, sigma, t.size), profile.min_range_m, profile.max_range_m)
    direction_sensor = d @ pose[:3, :3]  # R^T d, row-wise
    return SynthFrame(
        xyz=(direction_sensor * range_m[:, None])[seen].astype(np.float32),
        intensity=profile.intensity.from_reflectivity(reflectivity[seen]),
        labels=((inst.astype(np.uint32) << np.uint32(16)) | sem)[seen].astype(np.uint32),
        ring=ring[seen],
        pose=pose,
        time_s=time_s,
        reflectivity=reflectivity[seen].astype(np.float32),
        part=part[seen],
    )


def detection_limit(profile: SensorProfile) -> float:
    """The synthetic sensor's detection limit, reflectivity / m^2: a return of reflectivity
    rho (texture included, no incidence term) at range R is kept when rho / R^2 reaches it."""
    return DETECTED_RHO / profile.max_range_m**2


def _in_file_order(
    beams: geo.Beams, t_hit: geo.F64, prim: npt.NDArray[np.int32], profile: SensorProfile
) -> tuple[npt.NDArray[np.int64], geo.F64, geo.F64, npt.NDArray[np.int32]]:
    """Ring, direction (M, 3), distance and primitive of the beams with a hit in range.

    Top channel first, each ring in azimuth order: reverse the rows, flatten row-major.
    """
    t_top = t_hit[::-1]
    flat = np.flatnonzero((t_top >= profile.min_range_m) & (t_top <= profile.max_range_m))
    ring = (t_hit.shape[0] - 1 - flat // t_hit.shape[1]).astype(np.int64)
    d = np.stack([a[::-1].reshape(-1)[flat] for a in (beams.dx, beams.dy, beams.dz)], axis=1)
    return ring, d, t_top.reshape(-1)[flat], prim[::-1].reshape(-1)[flat]


def _point_parts(
    scene: Scene, pid: npt.NDArray[np.int32], point: geo.F64, pose: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint16], npt.NDArray[np.float32]]:
    """Part, instance id and per-object reflectance factor of each hit."""
    obj = pid >= 0
    safe = np.where(obj, pid, 0)
    prims = scene.prims
    part = np.where(obj, prims.part[safe], 0).astype(np.uint8)
    inst = np.where(obj, prims.instance[safe], 0).astype(np.uint16)
    rho_scale = np.where(obj, prims.rho_scale[safe], 1.0).astype(np.float32)
    ground = ~obj
    x, y = point[ground, 0] + pose[0, 3], point[ground, 1] + pose[1, 3]
    raised = (pid[ground] == geo.CURB_FACE) | (np.abs(y) >= ROAD_HALF_WIDTH_M)
    part[ground] = scene.ground_part(x, y, raised)
    return part, inst, rho_scale
