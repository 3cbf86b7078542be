"""nuScenes-lidarseg: LIDAR_TOP `.pcd.bin` scans with uint8 lidarseg labels.

Layout (docs/formats.md §2), relative to the dataroot:

    samples/LIDAR_TOP/<log>__LIDAR_TOP__<us>.pcd.bin   keyframes; headerless little-endian
                                                       float32, N x 5: x, y, z in m (sensor
                                                       frame), intensity 0-255, ring 0-31
    sweeps/LIDAR_TOP/...pcd.bin                        non-keyframes, same format, no labels
    lidarseg/<version>/<sd_token>_lidarseg.bin         uint8 per point (category `index`)
    panoptic/<version>/<sd_token>_panoptic.npz         npz key `data`: uint16 per point,
                                                       category index * 1000 + instance id
    <version>/*.json                                   the tables; copied byte for byte
    maps/**                                            map files; copied byte for byte

Scans are read and written here with all five columns: the devkit's
`LidarPointCloud.from_file` drops the ring column and must never produce output.
The devkit only walks the tables (`items()`), which also checks the database the way every
nuScenes user will (13 tables, #label files == #lidarseg records, map files exist). Loading
the v1.0-trainval tables this way takes about a minute and several GB of memory, once per
build.

Panoptic `.npz` files are zip archives whose members carry the time they were written
(`np.savez_compressed`), so the original bytes cannot be reproduced; encode writes a
deterministic archive instead (one member `data.npy`, deflated, dated 1980-01-01) that the
devkit and `np.load` read as the same array. Round trips compare decoded arrays for that
role; scans and lidarseg labels round-trip byte for byte.
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError, CorruptItemError, DatasetNotFoundError, ReaderError
from lads.frame import Frame, Item
from lads.readers.base import (
    EncodedFile,
    check_finite,
    encode_labels,
    encode_scan_and_labels,
    read_labels,
    read_records,
)
from lads.readers.poses import PoseTrack

TABLES = (
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
)
# The tables a scan's pose and time come from (`pose_relpaths`).
POSE_TABLES = ("ego_pose", "calibrated_sensor", "sample_data")
CHANNEL = "LIDAR_TOP"
# Why a nuScenes scan file holds exactly nuScenes' five columns (`Reader.record_fixed_by`).
DEVKIT_RECORD = (
    "nuscenes-devkit, whose LidarPointCloud.from_file reads every .pcd.bin as 5 float32 "
    "columns (x, y, z, intensity, ring)"
)
PANOPTIC_DTYPE = np.dtype(np.uint16)
_NPZ_DATE = (1980, 1, 1, 0, 0, 0)


def npz_bytes(data: np.ndarray) -> bytes:
    """A deterministic `.npz` holding `data` under key "data" (what np.savez_compressed
    writes, minus the write time)."""
    npy = io.BytesIO()
    np.lib.format.write_array(npy, np.ascontiguousarray(data), allow_pickle=False)
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        info = zipfile.ZipInfo("data.npy", date_time=_NPZ_DATE)
        info.compress_type = zipfile.ZIP_DEFLATED
        info.external_attr = 0o644 << 16
        zf.writestr(info, npy.getvalue())
    return out.getvalue()


class NuScenesReader:
    """Reader and encoder of nuScenes LIDAR_TOP scans with lidarseg (and panoptic) labels.

    Args:
        root: the nuScenes dataroot (holds `samples/`, `lidarseg/`, `v1.0-*/`, `maps/`).
        version: table folder, e.g. "v1.0-mini"; None picks the only `v1.0-*` folder of root
            (ConfigError when there are several).
        include_sweeps: also list the non-keyframe LIDAR_TOP sample_data (unlabelled
            items).

    Items: every LIDAR_TOP keyframe with a lidarseg record (every LIDAR_TOP keyframe when
    the version has no lidarseg.json, e.g. v1.0-test), plus the sweeps on request, whether
    their files exist or not (a missing file fails its item at read time, naming it);
    relpath = sample_data filename, label_relpath = lidarseg filename, extra role
    "panoptic" when a panoptic record exists, meta (("sample_data_token", token),).

    Frames: columns ("x", "y", "z", "intensity", "ring"); points (N, 5) float32; labels (N,)
    uint8 lidarseg or None; extra_labels["panoptic"] (N,) uint16.
    """

    name = "nuscenes"
    sensor = "hdl32e"
    particle_label = 0  # "noise": dust, fog, raindrops, smoke
    label_set = "nuscenes"
    columns: tuple[str, ...] = ("x", "y", "z", "intensity", "ring")
    record_fixed_by: str | None = DEVKIT_RECORD
    label_dtype = np.dtype(np.uint8)

    def __init__(
        self, root: str | Path, *, version: str | None = None, include_sweeps: bool = False
    ):
        self.root = Path(root)
        self.version = version
        self.include_sweeps = bool(include_sweeps)
        # The poses of the items `items()` listed, kept compact (a row of ego_pose translation,
        # rotation, then calibrated_sensor translation, rotation per item, by relpath) and
        # turned into matrices only when a sensor transfer asks (`sensor_poses`).
        self._pose_rows: dict[str, int] = {}
        self._pose_table = np.zeros((0, 14))
        # Per scene, (timestamp us, relpath) of its items in time order (`pose_track`).
        self._scenes: dict[str, list[tuple[int, str]]] = {}

    def __repr__(self) -> str:
        return (
            f"NuScenesReader({str(self.root)!r}, version={self.version!r}, "
            f"include_sweeps={self.include_sweeps})"
        )

    @staticmethod
    def keyframe_filename(log: str, timestamp_us: int) -> str:
        """The file name of a LIDAR_TOP scan recorded in `log` (e.g.
        "n015-2018-07-24-11-22-45+0800") at `timestamp_us` (µs since the Unix epoch):
        `<log>__LIDAR_TOP__<us>.pcd.bin`, as every nuScenes scan file is named."""
        return f"{log}__{CHANNEL}__{int(timestamp_us)}.pcd.bin"

    def new_item(self, filename: str, sample_data_token: str, version: str) -> Item:
        """The item of a new labelled LIDAR_TOP keyframe whose scan file is `filename`
        (`keyframe_filename`) and whose sample_data (and lidarseg record) token is
        `sample_data_token`, in the tables of `version` (e.g. "v1.0-mini"): scan
        `samples/LIDAR_TOP/<filename>`, label `lidarseg/<version>/<token>_lidarseg.bin`,
        meta (("sample_data_token", token),). `items()` lists the same files once the
        tables name them, and adds the scene, timestamp and scan number to the meta.

        Not part of the `Reader` protocol: for writers of new trees (`lads synth`), which
        build a `Frame` of this item (points (N, 5), labels uint8), write the files `encode`
        returns and the tables themselves (sample_data.filename = relpath, lidarseg.filename
        = label_relpath).
        """
        return Item(
            self.name,
            f"samples/{CHANNEL}/{filename}",
            f"lidarseg/{version}/{sample_data_token}_lidarseg.bin",
            meta=(("sample_data_token", sample_data_token),),
        )

    def resolved_version(self) -> str:
        """The table folder name; DatasetNotFoundError / ConfigError when none or ambiguous."""
        if not self.root.is_dir():
            raise DatasetNotFoundError(
                f"{self.root}: no such folder; expected a nuScenes dataroot holding samples/, "
                "lidarseg/ and a v1.0-* table folder."
            )
        if self.version is not None:
            if not (self.root / self.version).is_dir():
                raise DatasetNotFoundError(
                    f"{self.root / self.version}: no such table folder; expected the nuScenes "
                    f"tables of version {self.version!r} there. Check the version option."
                )
            return self.version
        found = sorted(d.name for d in self.root.glob("v1.0-*") if d.is_dir())
        if not found:
            raise DatasetNotFoundError(
                f"{self.root}: no v1.0-* table folder; expected a nuScenes dataroot with e.g. "
                "v1.0-mini/ (unpack the metadata and lidarseg archives there), or, for loose "
                "scan files without tables, --source nuscenes-scans."
            )
        if len(found) > 1:
            raise ConfigError(
                f"{self.root}: several nuScenes versions {found}; pass version= one of them."
            )
        return found[0]

    def items(self) -> list[Item]:
        """Walk the tables with nuscenes-devkit; sorted by relpath."""
        version = self.resolved_version()
        table_root = self.root / version
        nusc = self._devkit(table_root, version)
        items, rows = self._lidar_items(nusc)
        if not items:
            raise DatasetNotFoundError(
                f"{table_root}: no {CHANNEL} sample_data with lidarseg labels"
                f"{' or sweep files' if self.include_sweeps else ''}; expected lidarseg.json "
                "records for the LIDAR_TOP keyframes. Unpack the lidarseg archive."
            )
        self._pose_rows = {rel: k for k, rel in enumerate(rows)}
        self._pose_table = np.array(list(rows.values()), dtype=np.float64).reshape(-1, 14)
        numbered = _numbered(items)
        self._scenes = {}
        for it in sorted(numbered, key=lambda it: int(dict(it.meta)["scan_number"])):
            meta = dict(it.meta)
            self._scenes.setdefault(meta["scene"], []).append((int(meta["timestamp"]), it.relpath))
        return sorted(numbered, key=lambda it: it.relpath)

    def _devkit(self, table_root: Path, version: str) -> Any:
        """The devkit's NuScenes database of `version`, after checking its tables exist.

        Raises:
            DatasetNotFoundError: a table is missing.
            ReaderError: nuscenes-devkit is not installed or cannot load the database.
        """
        missing = [f"{t}.json" for t in TABLES if not (table_root / f"{t}.json").is_file()]
        if missing:
            raise DatasetNotFoundError(
                f"{table_root}: missing nuScenes tables {missing}; expected all 13 tables "
                f"({', '.join(TABLES)}) plus lidarseg.json. Unpack the metadata archive of "
                f"{version} (and then the lidarseg archive, whose category.json wins) there."
            )
        try:
            from nuscenes.nuscenes import NuScenes
        except ImportError as exc:
            raise ReaderError(
                f"{table_root}: listing nuScenes items needs nuscenes-devkit ({exc}); "
                "install it with: pip install nuscenes-devkit==1.2.0"
            ) from exc
        try:
            nusc = NuScenes(version=version, dataroot=str(self.root), verbose=False)
        except Exception as exc:  # devkit asserts and KeyErrors: wrap with context
            subset = _recorded_subset(self.root)
            if subset:
                raise ReaderError(
                    f"{self.root}: a lads tree built with --limit ({subset[0]} of {subset[1]} "
                    "items); its copied "
                    "tables list every source frame, which nuscenes-devkit refuses. Build it "
                    f"without --limit to use it as a source ({type(exc).__name__}: {exc})."
                ) from exc
            raise ReaderError(
                f"{table_root}: nuscenes-devkit cannot load this database "
                f"({type(exc).__name__}: {exc}); expected consistent tables, one label file "
                f"per lidarseg/panoptic record in lidarseg|panoptic/{version}/ and every "
                "maps/ file the map table names. Fix or re-extract the dataset."
            ) from exc
        return nusc

    def _lidar_items(self, nusc: Any) -> tuple[list[Item], dict[str, tuple[float, ...]]]:
        """The LIDAR_TOP items (labelled keyframes, and sweeps when included) and, by
        relpath, the (14,) ego pose and calibration (translation, quaternion w, x, y, z)."""
        has_lidarseg = hasattr(nusc, "lidarseg")
        lidarseg = {r["sample_data_token"]: r["filename"] for r in getattr(nusc, "lidarseg", [])}
        panoptic = {r["sample_data_token"]: r["filename"] for r in getattr(nusc, "panoptic", [])}
        items = []
        rows: dict[str, tuple[float, ...]] = {}
        for sd in nusc.sample_data:
            if sd["channel"] != CHANNEL:
                continue
            token, filename = sd["token"], sd["filename"]
            # Every record is an item, whether its file is there or not: a missing or broken
            # file becomes a failed item with its reason, never a silent gap.
            if sd["is_key_frame"]:
                if has_lidarseg and token not in lidarseg:
                    continue
            elif not self.include_sweeps:
                continue
            extras = (("panoptic", panoptic[token]),) if token in panoptic else ()
            scene = nusc.get("sample", sd["sample_token"])["scene_token"]
            meta = (
                ("sample_data_token", token),
                ("scene", scene),
                ("timestamp", str(int(sd["timestamp"]))),
            )
            items.append(Item(self.name, filename, lidarseg.get(token), extras, meta))
            ego = nusc.get("ego_pose", sd["ego_pose_token"])
            calib = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
            rows[filename] = (
                *ego["translation"],
                *ego["rotation"],
                *calib["translation"],
                *calib["rotation"],
            )
        return items, rows

    def scan_position(self, item: Item) -> tuple[str, int]:
        """(scene token, scan number) of an item: its place in time among the scene's items,
        for a sensor transfer's window (`lads.transfer.window`)."""
        meta = dict(item.meta)
        return meta["scene"], int(meta["scan_number"])

    def pose_relpaths(self, item: Item) -> list[str]:
        """The tables an item's pose and time come from (ego_pose, calibrated_sensor and
        sample_data of its version): sources of every output built from the poses."""
        version = self.resolved_version()
        return [f"{version}/{name}.json" for name in POSE_TABLES]

    def sensor_poses(self, items: list[Item]) -> dict[str, npt.NDArray[np.float64]]:
        """(4, 4) lidar -> global pose of each item: its sample_data's ego_pose times its
        calibrated_sensor (lists the items first when this reader has not)."""
        if any(it.relpath not in self._pose_rows for it in items):
            self.items()
        return {it.relpath: self._pose_of(it.relpath) for it in items}

    def _pose_of(self, relpath: str) -> npt.NDArray[np.float64]:
        from pyquaternion import Quaternion  # nuscenes-devkit's own quaternion library

        row = self._pose_table[self._pose_rows[relpath]]
        ego = Quaternion(row[3:7]).transformation_matrix
        ego[:3, 3] = row[0:3]
        calib = Quaternion(row[10:14]).transformation_matrix
        calib[:3, 3] = row[7:10]
        return ego @ calib  # type: ignore[no-any-return]

    def pose_track(self, item: Item) -> PoseTrack:
        """The item and the items of its scene just before and after it in time (the listed
        ones: keyframes, and sweeps when included), with their poses and timestamps."""
        if item.relpath not in self._pose_rows:
            self.items()
        meta = dict(item.meta)
        scene = self._scenes[meta["scene"]]
        k = [rel for _, rel in scene].index(item.relpath)
        times = np.array([t for t, _ in scene], dtype=np.float64) * 1e-6
        poses = np.stack([self._pose_of(rel) for _, rel in scene[max(k - 1, 0) : k + 2]])
        lo = max(k - 1, 0)
        return PoseTrack(times[lo : lo + len(poses)], poses, k - lo, f"scene {meta['scene']}")

    def copied_files(self) -> list[str]:
        """Every file of `<version>/` (the JSON tables) and of `maps/`, recursively."""
        version = self.resolved_version()
        out: list[str] = []
        for folder in (version, "maps"):
            base = self.root / folder
            if base.is_dir():
                out.extend(
                    p.relative_to(self.root).as_posix() for p in base.rglob("*") if not p.is_dir()
                )
        return sorted(out)

    def read(self, item: Item) -> Frame:
        """Scan (N, 5) float32, lidarseg labels (N,) uint8, panoptic (N,) uint16."""
        path = self.root / item.relpath
        points = read_records(
            path, np.float32, 5, "nuScenes LIDAR_TOP scan (N x 5 float32: x, y, z, intensity, ring)"
        )
        check_finite(points, path, self.columns)
        n = points.shape[0]
        labels = None
        if item.label_relpath is not None:
            labels = read_labels(
                self.root / item.label_relpath,
                self.label_dtype,
                n,
                "nuScenes lidarseg labels (uint8 per point)",
                path,
                why="lidarseg.json lists it for this sample_data",
            )
        extras = {
            role: self._read_panoptic(self.root / rel, n, path) for role, rel in item.extra_relpaths
        }
        return Frame.from_source(item, self.sensor, self.columns, points, labels, extras)

    @staticmethod
    def _read_panoptic(path: Path, n: int, scan: Path) -> np.ndarray:
        what = "nuScenes panoptic labels (npz key 'data', uint16 per point)"
        if not path.is_file():
            raise CorruptItemError(
                f"{path}: missing {what} for scan {scan}; panoptic.json lists it. Restore it "
                "from the panoptic archive."
            )
        try:
            with np.load(path, allow_pickle=False) as npz:
                data = np.asarray(npz["data"])
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise CorruptItemError(
                f"{path}: cannot read {what} ({type(exc).__name__}: {exc}); re-extract it."
            ) from exc
        if data.shape != (n,) or data.dtype.kind not in "iu":
            raise CorruptItemError(
                f"{path}: holds {data.dtype} {data.shape} but scan {scan} has {n} points; "
                f"expected {what}. Re-extract both files from the dataset archives."
            )
        if data.size and (int(data.min()) < 0 or int(data.max()) > np.iinfo(PANOPTIC_DTYPE).max):
            raise CorruptItemError(
                f"{path}: values {int(data.min())}..{int(data.max())} outside uint16; "
                f"expected {what}."
            )
        return data.astype(PANOPTIC_DTYPE, copy=False)

    def encode(self, frame: Frame) -> list[EncodedFile]:
        """Scan (M x 20 bytes), lidarseg labels (M bytes), panoptic npz (deterministic)."""
        item = frame.item
        n = frame.points.shape[0]
        files = encode_scan_and_labels(frame, 5, self.label_dtype)
        for role, rel in item.extra_relpaths:
            # Checks shape and range via the raw encoding, then wraps it in an npz.
            raw = encode_labels(
                frame.extra_labels.get(role), PANOPTIC_DTYPE, n, rel, role, item.item_id
            )
            data = np.frombuffer(raw.payload, dtype=PANOPTIC_DTYPE.newbyteorder("<"))
            files.append(EncodedFile(rel, role, npz_bytes(data), n, 0))
        return files


def _recorded_subset(root: Path) -> tuple[int, int] | None:
    """`lads.built_tree.trial_subset` of the run.json at `root` (a lads tree), if any."""
    from lads.built_tree import RUN_JSON, trial_subset

    try:
        return trial_subset(json.loads((root / RUN_JSON).read_text()))
    except (OSError, ValueError):
        return None


def _numbered(items: list[Item]) -> list[Item]:
    """The items with a `scan_number` meta: their rank in time among their scene's items."""
    by_scene: dict[str, list[Item]] = {}
    for it in items:
        by_scene.setdefault(dict(it.meta)["scene"], []).append(it)
    out = []
    for scene_items in by_scene.values():
        ranked = sorted(scene_items, key=lambda it: (int(dict(it.meta)["timestamp"]), it.relpath))
        out += [
            replace(it, meta=(*it.meta, ("scan_number", str(k)))) for k, it in enumerate(ranked)
        ]
    return out
