"""nuScenes-lidarseg dataroots: the JSON tables, labels and scans (docs/formats.md §2).

`nuscenes_tables` builds the 13 tables (+ lidarseg.json / panoptic.json) of a one-log,
one-scene database around LIDAR_TOP sample_data records, plus the map PNG the map table
names; it is used by `lads synth --layout nuscenes` (lads/synth/writer.py) and by the tests'
tree builders (tests/trees.py). What `NuScenes(version, dataroot)` asserts (docs/formats.md §2.5):
all 13 tables load; category has `index` when lidarseg.json exists; #label files ==
#lidarseg records; every map PNG exists; map records have log_tokens.

Synthetic frames become nuScenes data as follows:

- Axes. nuScenes LIDAR_TOP has x right, y forward, z up; the synthetic sensor (KITTI
  convention) has x forward, y left. Scans are rotated by +90 deg about z (x_n = -y, y_n =
  x: a swap and a sign flip, exact in float32), and calibrated_sensor holds the matching
  exact -90 deg yaw (sensor -> ego), as the real LIDAR_TOP does (about -90 deg plus a small
  tilt). The ego frame is the synthetic sensor frame moved down and back by
  SENSOR_TRANSLATION, so ego_pose (ego -> global) sits on the road (z = 0) and global is the
  synthetic world frame.
- Mount. SENSOR_TRANSLATION = (0.943713, 0, 1.73): the real LIDAR_TOP's forward offset, but
  the synthetic street's sensor height (KITTI's 1.73 m, not nuScenes' 1.84 m), so geometry
  stays consistent.
- Points keep the synthetic order (ring by ring, top first), not the HDL-32E firing order
  (rings interleaved); the ring column is the channel, 0 = lowest beam.
- Intensity is the sensor profile's own encoding: the hdl32e byte codes (integers 0-255 as
  float32) for nuScenes' own sensor, another profile's values for a street that sensor
  scanned (read it with that --sensor).
- Labels: SemanticKITTI raw ids -> lidarseg `index` via nuscenes_lidarseg.yaml.
"""

from __future__ import annotations

import hashlib
import json
import re
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError
from lads.readers.nuscenes import CHANNEL, TABLES

# The class table lives in nuscenes_classes; importers take it from here too.
from lads.synth.nuscenes_classes import CLASSES_FILE as CLASSES_FILE
from lads.synth.nuscenes_classes import LidarsegClasses as LidarsegClasses
from lads.synth.nuscenes_classes import lidarseg_classes as lidarseg_classes

VERSION = "v1.0-mini"
# Real nuScenes LIDAR_TOP calibration (v1.0-mini, calibrated_sensor of scene-0061).
REAL_SENSOR_TRANSLATION = (0.943713, 0.0, 1.84023)
REAL_SENSOR_ROTATION = (
    0.7077955119163518,
    -0.006492242056004365,
    0.010646214713995808,
    -0.7063073142877817,
)
# nuScenes sensor frame from the synthetic (KITTI-convention) one: x_n = -y, y_n = x, z_n = z.
NUSC_FROM_SYNTH = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def token(text: str) -> str:
    """A deterministic 32-hex nuScenes-style token (first half of the text's SHA-256)."""
    return hashlib.sha256(text.encode()).hexdigest()[:32]


@dataclass(frozen=True)
class NuscSampleData:
    """One LIDAR_TOP sample_data record to put in the tables (its files written elsewhere).

    Attributes:
        token: sample_data token (also the lidarseg/panoptic record's token).
        filename: relative to the dataroot; its `__<us>.pcd.bin` suffix is the timestamp.
        key_frame: a sample (keyframe) or a sweep.
        lidarseg: filename of its lidarseg label file, if any.
        panoptic: filename of its panoptic npz, if any.
        ego_translation: ego -> global translation of its ego_pose, m.
        ego_rotation: ego -> global rotation of its ego_pose, quaternion w, x, y, z.
    """

    token: str
    filename: str
    key_frame: bool
    lidarseg: str | None = None
    panoptic: str | None = None
    ego_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ego_rotation: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class NuscScene:
    """The one log, scene and LIDAR_TOP calibration of a database (defaults: a real log name
    and the real LIDAR_TOP calibration).

    Attributes:
        salt: prefix of every table-level token (log, scene, sensor, calibration, map), so
            databases from different seeds get different tokens.
    """

    logfile: str = "n015-2018-07-24-11-22-45+0800"
    vehicle: str = "n015"
    date_captured: str = "2018-07-24"
    location: str = "singapore-onenorth"
    name: str = "scene-0001"
    description: str = "lads test scene"
    sensor_translation: tuple[float, float, float] = REAL_SENSOR_TRANSLATION
    sensor_rotation: tuple[float, float, float, float] = REAL_SENSOR_ROTATION
    salt: str = field(default="")


def quaternion_wxyz(rotation: npt.ArrayLike) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z), w >= 0, of a (3, 3) rotation matrix (Shepperd's method)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    arr = np.asarray(q) / np.linalg.norm(q)
    if arr[0] < 0.0:
        arr = -arr
    w, x, y, z = (float(v) + 0.0 for v in arr)  # + 0.0 turns -0.0 into 0.0
    return w, x, y, z


# ----------------------------------------------------------------------------------------
# Synthetic frames as nuScenes data

# Synthetic sensor -> ego: the ego frame is the sensor frame shifted (see the module doc).
SENSOR_TRANSLATION = (0.943713, 0.0, 1.73)
SENSOR_ROTATION = quaternion_wxyz(NUSC_FROM_SYNTH.T)  # exact -90 deg yaw: (0.7071, 0, 0, -0.7071)


def nuscenes_points(
    xyz: npt.NDArray[np.float32],
    intensity: npt.NDArray[np.float32],
    ring: npt.NDArray[np.int64],
) -> npt.NDArray[np.float32]:
    """(N, 5) float32 points x, y, z (m), intensity, ring of a synthetic frame as the
    nuScenes reader's frames hold them: axes rotated to nuScenes LIDAR_TOP, intensity in the
    frame's sensor's own encoding (hdl32e: byte codes 0-255), ring the channel index (0 =
    lowest beam)."""
    cols = [-xyz[:, 1], xyz[:, 0], xyz[:, 2], intensity, ring.astype(np.float32)]
    return np.column_stack(cols).astype(np.float32)


def ego_pose_of(
    sensor_pose: npt.NDArray[np.float64],
) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """ego -> global (translation, quaternion w, x, y, z) of a synthetic sensor -> world pose:
    R = R_sensor, t = t_sensor - R_sensor @ SENSOR_TRANSLATION."""
    rot = np.asarray(sensor_pose, dtype=np.float64)[:3, :3]
    t = np.asarray(sensor_pose, dtype=np.float64)[:3, 3] - rot @ np.asarray(SENSOR_TRANSLATION)
    x, y, z = (float(v) + 0.0 for v in t)
    return (x, y, z), quaternion_wxyz(rot)


# ----------------------------------------------------------------------------------------
# Tables


def _timestamp(filename: str) -> int:
    match = re.search(r"__(\d+)\.pcd\.bin$", filename)
    return int(match.group(1)) if match else 0


def tiny_png() -> bytes:
    """A valid 1 x 1 black 8-bit greyscale PNG (uncompressed deflate, so byte-stable)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data)
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b"\x00\x00", 0))
        + chunk(b"IEND", b"")
    )


def map_relpath(version: str, scene: NuscScene) -> str:
    """The map PNG the map table of `nuscenes_tables(version, ..., scene)` names."""
    return f"maps/{token(f'{scene.salt}{version}:map')}.png"


def table_files(version: str, *, lidarseg: bool, panoptic: bool = False) -> list[str]:
    """Relative paths of the JSON tables `nuscenes_tables` writes."""
    names = [*TABLES, *(["lidarseg"] if lidarseg else []), *(["panoptic"] if panoptic else [])]
    return [f"{version}/{n}.json" for n in names]


def nuscenes_tables(
    version: str, records: list[NuscSampleData], scene: NuscScene | None = None
) -> dict[str, bytes]:
    """File contents by relative path: `<version>/*.json` and the map PNG.

    One log and one scene; keyframes become consecutive samples linked prev/next; each sweep
    belongs to the next keyframe's sample (the last one's after the last keyframe); all
    records are chained prev/next in timestamp order; one ego_pose per record. lidarseg.json
    and panoptic.json are written when any record has such a file; category.json always
    carries `index` (the lidarseg edition).
    """
    scene = scene or NuscScene()
    ordered = sorted(records, key=lambda r: (_timestamp(r.filename), r.filename))
    keys = [r for r in ordered if r.key_frame]
    if not keys:
        raise ConfigError("nuScenes tables need at least one keyframe record.")
    content = _tables(version, scene, ordered, keys)
    for role in ("lidarseg", "panoptic"):
        rows = [
            {"token": r.token, "sample_data_token": r.token, "filename": getattr(r, role)}
            for r in ordered
            if getattr(r, role)
        ]
        if rows:
            content[role] = rows
    files = {
        f"{version}/{name}.json": json.dumps(rows, indent=0).encode()
        for name, rows in content.items()
    }
    files[map_relpath(version, scene)] = (
        tiny_png()
    )  # NuScenes() asserts it exists; pixels load lazily
    return files


# The one visibility level the tables list (no annotations refer to it).
_VISIBILITY = {
    "token": "1",
    "level": "v0-40",
    "description": "visibility of whole object is between 0 and 40%",
}


def _tables(
    version: str, scene: NuscScene, ordered: list[NuscSampleData], keys: list[NuscSampleData]
) -> dict[str, list[dict[str, Any]]]:
    """The 13 tables by name, of `ordered` records (timestamp order) whose keyframes are
    `keys`."""
    log, scene_token, sensor, calib, map_token = (
        token(f"{scene.salt}{version}:{k}") for k in ("log", "scene", "sensor", "calib", "map")
    )
    samples = [token(f"sample:{r.token}") for r in keys]
    sd_rows, ego_rows = _record_rows(ordered, keys, samples, calib)
    return {
        "category": _category_rows(),
        "attribute": [],
        "visibility": [_VISIBILITY],
        "instance": [],
        "sensor": [{"token": sensor, "channel": CHANNEL, "modality": "lidar"}],
        "calibrated_sensor": [
            {
                "token": calib,
                "sensor_token": sensor,
                "translation": list(scene.sensor_translation),
                "rotation": list(scene.sensor_rotation),
                "camera_intrinsic": [],
            }
        ],
        "ego_pose": ego_rows,
        "log": [
            {
                "token": log,
                "logfile": scene.logfile,
                "vehicle": scene.vehicle,
                "date_captured": scene.date_captured,
                "location": scene.location,
            }
        ],
        "scene": _scene_rows(scene, scene_token, log, samples),
        "sample": _sample_rows(keys, samples, scene_token),
        "sample_data": sd_rows,
        "sample_annotation": [],
        "map": [
            {
                "category": "semantic_prior",
                "token": map_token,
                "filename": map_relpath(version, scene),
                "log_tokens": [log],
            }
        ],
    }


def _category_rows() -> list[dict[str, Any]]:
    """The category table: one row per lidarseg class, with its label `index`."""
    return [
        {"token": token(f"category:{name}"), "name": name, "description": name, "index": i}
        for i, name in enumerate(lidarseg_classes().categories)
    ]


def _scene_rows(
    scene: NuscScene, scene_token: str, log: str, samples: list[str]
) -> list[dict[str, Any]]:
    """The scene table: the one scene of log `log`, from the first sample to the last."""
    return [
        {
            "token": scene_token,
            "log_token": log,
            "nbr_samples": len(samples),
            "first_sample_token": samples[0],
            "last_sample_token": samples[-1],
            "name": scene.name,
            "description": scene.description,
        }
    ]


def _sample_rows(
    keys: list[NuscSampleData], samples: list[str], scene_token: str
) -> list[dict[str, Any]]:
    """The sample table: one sample per keyframe, linked prev/next."""
    return [
        {
            "token": s,
            "timestamp": _timestamp(r.filename),
            "prev": samples[i - 1] if i else "",
            "next": samples[i + 1] if i + 1 < len(samples) else "",
            "scene_token": scene_token,
        }
        for i, (s, r) in enumerate(zip(samples, keys, strict=True))
    ]


def _record_rows(
    ordered: list[NuscSampleData], keys: list[NuscSampleData], samples: list[str], calib: str
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The sample_data and ego_pose tables: one row each per record, chained prev/next; a
    sweep belongs to the next keyframe's sample (the last one's after the last keyframe)."""
    sd_rows, ego_rows = [], []
    for i, r in enumerate(ordered):
        later = [
            s
            for s, k in zip(samples, keys, strict=True)
            if _timestamp(k.filename) >= _timestamp(r.filename)
        ]
        sample = samples[keys.index(r)] if r.key_frame else (later[0] if later else samples[-1])
        ego = token(f"ego:{r.token}")
        ego_rows.append(
            {
                "token": ego,
                "timestamp": _timestamp(r.filename),
                "rotation": list(r.ego_rotation),
                "translation": list(r.ego_translation),
            }
        )
        sd_rows.append(
            {
                "token": r.token,
                "sample_token": sample,
                "ego_pose_token": ego,
                "calibrated_sensor_token": calib,
                "timestamp": _timestamp(r.filename),
                "fileformat": "pcd",
                "is_key_frame": r.key_frame,
                "height": 0,
                "width": 0,
                "filename": r.filename,
                "prev": ordered[i - 1].token if i else "",
                "next": ordered[i + 1].token if i + 1 < len(ordered) else "",
            }
        )
    return sd_rows, ego_rows
