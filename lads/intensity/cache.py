"""The range-image cache of a training run: every training frame's model inputs, in zarr.

Layout: `RUN/cache.zarr/<pair>/<role>/<frame>/` with arrays `inputs` (C, H, W) float32,
`target` (H, W) float32 reflectivity (when the frame has an intensity) and `classes` (H, W)
int32, the class id of each pixel's point (-1: empty or unlabelled; a law keyed by class
reads it, `lads.intensity.law_reference`), and attributes
`key` (hash of what decides the content), `labelled`, `extinction_per_m`, `sensor` and
`done`. A frame is complete once `done` is written, after its arrays; a rerun skips complete
frames whose key matches and rebuilds the rest, so a killed preparation resumes. Frames are
made in parallel with joblib (each job writes only its own group).

Statistics for normalisation and decoding (`lads.intensity.cache_statistics`) are computed
from the cache over *occupied
pixels only* and keyed to the run's data hash (docs/physics.md §10.4, §10.7 item 6).
`cache_fingerprint` names the exact cached frames they were computed from, so a stored copy
(`statistics_to_json`, read back exactly by `statistics_from_json`) is reused only while
the cache it describes is unchanged.
"""

from __future__ import annotations

import functools
import hashlib
import json
import urllib.parse
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt
import zarr
from joblib import Parallel, delayed
from tqdm.auto import tqdm

from lads.errors import ConfigError, LadsError, TrainingError
from lads.frame import Frame, Item
from lads.intensity.features import FEATURE_VERSION, FrameImage, channel_names, frame_image
from lads.intensity.splits import split_frames
from lads.intensity.train_config import DomainSpec, TrainConfig, weather_physics_version
from lads.physics.materials import class_ids
from lads.physics.projection import MIN_RANGE_M
from lads.readers import label_set_for
from lads.sensors.profile import SensorProfile, load_profile

CACHE_NAME = "cache.zarr"
ROLES = ("source", "target")
# Bumped when a cached frame holds other arrays: 2 added the per-pixel class plane.
CACHE_LAYOUT = "2"


@dataclass(frozen=True, slots=True)
class CacheJob:
    """One frame to cache: pair key, role, its domain, and which frame (relpath or index)."""

    pair: str
    role: str
    domain: DomainSpec
    frame: str
    kind: str
    range_exponent: float
    tag: str = ""  # which dataset of the role ("" the domain itself, "also1", ...)
    # Label set of the pair's target: only frames labelled in it get a class plane.
    class_label_set: str | None = None

    @property
    def key(self) -> str:
        payload: dict[str, Any] = {
            "job": asdict(self),
            "features": FEATURE_VERSION,
            "layout": CACHE_LAYOUT,
        }
        if self.domain.weather:
            payload["weather_physics"] = weather_physics_version()
        payload["job"]["domain"] = _hashed_domain(self.domain)
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:20]

    @property
    def node(self) -> str:
        name = urllib.parse.quote(self.frame, safe="")
        return f"{self.pair}/{self.role}/{self.tag + '~' if self.tag else ''}{name}"


@dataclass(frozen=True, slots=True)
class CachedFrame:
    """One cached frame, read back into memory."""

    pair: str
    role: str
    frame: str
    inputs: npt.NDArray[np.float32]
    target: npt.NDArray[np.float32] | None
    labelled: bool
    extinction_per_m: float
    sensor: str
    classes: npt.NDArray[np.int32] | None = None  # (H, W) class id per pixel, -1 none

    def plane(self, name: str) -> npt.NDArray[np.float32]:
        """(H, W) the raw input channel `name` (the channel set follows from the count)."""
        return self.inputs[
            channel_names(self.inputs.shape[0] != len(channel_names(False))).index(name)
        ]

    @property
    def class_plane(self) -> npt.NDArray[np.int32]:
        """(H, W) class id per pixel; all -1 for a frame cached without a class plane."""
        if self.classes is not None:
            return self.classes
        return np.full(self.inputs.shape[1:], -1, dtype=np.int32)


def _hashed_domain(domain: DomainSpec) -> dict[str, Any]:
    """What of a domain decides its frames' content (not where the data lives)."""
    out = asdict(domain)
    for d in (out, *out["also"]):
        d.pop("data_root")
    return out


def list_jobs(cfg: TrainConfig) -> list[CacheJob]:
    """Every training frame of every pair and role: the train split of the role's domain
    and of each of its `also` datasets.

    Raises:
        TrainingError: a role yields no training frame, or a split pattern matches nothing.
    """
    jobs = []
    for pair in cfg.pairs:
        classes = label_set_for(pair.target.dataset)
        for role in ROLES:
            domain = pair.source if role == "source" else pair.target
            where = f"pairs.{pair.key}.{role}"
            found = [
                CacheJob(pair.key, role, d, f, cfg.kind, cfg.range_exponent, tag, classes)
                for tag, d in domain.members()
                for f in _frame_names(d, where)
            ]
            if not found:
                raise TrainingError(f"{where}: no training frame (every train split is empty).")
            jobs.extend(found)
    return jobs


def role_split(domain: DomainSpec, name: str, where: str) -> list[tuple[str, DomainSpec, str]]:
    """(tag, dataset, frame) of one split over a role's domain and its `also` datasets."""
    return [(tag, d, f) for tag, d in domain.members() for f in split_of(d, name, where)]


def split_of(domain: DomainSpec, name: str, where: str) -> list[str]:
    """The frames of one split ("train", "validation", "test") of a real domain; for
    "train" at most `domain.frames` of them (0 = all)."""
    try:
        frames = split_frames(_all_frames(domain), domain.split, where)[name]
    except ConfigError as exc:
        raise TrainingError(str(exc)) from None
    return frames[: domain.frames] if name == "train" and domain.frames else frames


def _frame_names(domain: DomainSpec, where: str) -> list[str]:
    """The training frames of one dataset of a role (synth: generated names)."""
    if domain.dataset == "synth":
        if domain.frames < 1:
            raise TrainingError(f"{where}: synth domains need frames >= 1.")
        return [f"synth-{i:06d}" for i in range(domain.frames)]
    return split_of(domain, "train", where)


def _all_frames(domain: DomainSpec) -> list[str]:
    return [item.relpath for item in _reader(domain).items()]


@functools.lru_cache(maxsize=4)
def _reader_items(dataset: str, root: str) -> tuple[Any, dict[str, Item]]:
    """A reader and its items by relpath, made once per process (walking a full nuScenes
    database takes a minute; it must not happen per frame)."""
    from lads.readers import get_reader

    reader = get_reader(dataset, root)
    return reader, {item.relpath: item for item in reader.items()}


def _reader(domain: DomainSpec) -> Any:
    return _reader_items(domain.dataset, str(domain.root_path()))[0]


@dataclass(frozen=True, slots=True)
class DomainFrame:
    """One real frame of a domain, ready for `frame_image`.

    Attributes:
        frame: the frame after the domain's physics weather (if any), zero-range points
            (lost beams, nuScenes ego returns) removed.
        profile: its sensor profile.
        label_set: material label set of its labels, None when unlabelled.
        ring: (N,) ring column or None.
        particle: (N,) bool labelled weather particles (weather models, real recordings).
        extinction_per_m: alpha of the frame's weather, 1/m.
    """

    frame: Frame
    profile: SensorProfile
    label_set: str | None
    ring: npt.NDArray[np.float32] | None
    particle: npt.NDArray[np.bool_] | None
    extinction_per_m: float


def read_domain_frame(domain: DomainSpec, relpath: str, *, weather_model: bool) -> DomainFrame:
    """Read one frame of a real domain through its reader and prepare it."""
    from lads.seeding import rng_for
    from lads.stages.weather import WeatherStage

    reader, items = _reader_items(domain.dataset, str(domain.root_path()))
    frame = reader.read(items[relpath])
    extinction = domain.extinction_per_m
    if domain.weather:
        params = {k: v for k, v in domain.weather.items() if k != "stage"}
        stage = WeatherStage(name=domain.weather["stage"], **params)
        frame = stage(frame, rng_for(domain.seed, frame.item.item_id, "train", stage.name))
        extinction = float(frame.condition("extinction_per_m", 0.0))  # type: ignore[arg-type]
    keep = np.flatnonzero(np.linalg.norm(frame.xyz.astype(np.float64), axis=1) > MIN_RANGE_M)
    frame = frame.select(
        keep,
        outcome=frame.outcome[keep],
        lost_rows=np.zeros(0, np.int64),
        points=frame.points[keep],
    )
    particle = None
    if weather_model and frame.labels is not None and not domain.weather:
        # Real weather recordings label their particles (WADS 110 = falling snow).
        lset = reader.label_set
        ids = frame.labels.astype(np.int64) if lset is None else class_ids(frame.labels, lset)
        particle = ids == reader.particle_label
    ring = frame.points[:, frame.columns.index("ring")] if "ring" in frame.columns else None
    label_set = label_set_for(domain.dataset) if frame.labels is not None else None
    profile = load_profile(domain.sensor or frame.sensor)
    return DomainFrame(frame, profile, label_set, ring, particle, extinction)


def job_image(job: CacheJob) -> tuple[FrameImage, float, str, npt.NDArray[np.int32]]:
    """The FrameImage of one job, the extinction (1/m) it was made with, its sensor
    profile name and its (H, W) class plane (`pixel_classes`): pure computation apart from
    reading the source frame."""
    domain = job.domain
    styles = job.kind == "weather"
    style = job.pair if styles else None
    if domain.dataset == "synth":
        from lads.synth import synth_frame

        sensor = domain.sensor or "hdl64e"
        index = int(job.frame.split("-")[1])
        sf = synth_frame(
            sensor,
            frames=domain.frames,
            seed=domain.seed,
            index=index,
            azimuth_bins=domain.azimuth_bins,
        )
        profile = load_profile(sensor)
        fi = frame_image(
            sf.xyz,
            profile,
            labels=sf.labels,
            label_set="semantickitti",
            ring=sf.ring,
            intensity=sf.intensity,
            style=style,
            styles=styles,
            range_exponent=job.range_exponent,
        )
        classes = pixel_classes(fi, sf.labels, "semantickitti", job.class_label_set)
        return fi, 0.0, profile.name, classes
    d = read_domain_frame(domain, job.frame, weather_model=styles)
    fi = frame_image(
        d.frame.xyz,
        d.profile,
        labels=d.frame.labels,
        label_set=d.label_set,
        ring=d.ring,
        intensity=d.frame.intensity,
        outcome=d.frame.outcome,
        particle=d.particle,
        style=style,
        styles=styles,
        range_exponent=job.range_exponent,
        extinction_per_m=d.extinction_per_m,
    )
    classes = pixel_classes(fi, d.frame.labels, d.label_set, job.class_label_set)
    return fi, d.extinction_per_m, d.profile.name, classes


def pixel_classes(
    fi: FrameImage, labels: npt.ArrayLike | None, label_set: str | None, wanted: str | None
) -> npt.NDArray[np.int32]:
    """(H, W) int32 class id of the point owning each pixel (instance bits dropped), -1 for
    empty pixels and for frames without labels or labelled in another set than `wanted`."""
    index = fi.image.index
    if labels is None or label_set is None or label_set != wanted:
        return np.full(index.shape, -1, dtype=np.int32)
    ids = class_ids(labels, label_set)
    return np.where(index >= 0, ids[np.maximum(index, 0)], -1).astype(np.int32)


def _build_one(root: str, job: CacheJob) -> str:
    try:
        fi, extinction_per_m, sensor, classes = job_image(job)
    except LadsError as exc:
        raise TrainingError(
            f"cache: frame {job.frame} of pair {job.pair} ({job.role}): {exc}"
        ) from None
    group = zarr.open_group(Path(root) / job.node, mode="w", zarr_format=3)
    arrays: dict[str, npt.NDArray[Any]] = {"inputs": fi.inputs, "classes": classes}
    if fi.target is not None:
        arrays["target"] = fi.target
    for name, values in arrays.items():
        arr = group.create_array(
            name, shape=values.shape, chunks=values.shape, dtype=values.dtype.name
        )
        arr[:] = values
    group.attrs.put(
        {
            "key": job.key,
            "labelled": bool(fi.labelled),
            "extinction_per_m": float(extinction_per_m),
            "sensor": sensor,
            "done": True,  # written last: the frame is complete
        }
    )
    return job.node


def build_cache(
    run_dir: Path, cfg: TrainConfig, *, jobs: int | None = None, progress: bool = True
) -> list[CacheJob]:
    """Make (or complete) the cache of a run; returns its jobs. Raises TrainingError."""
    root = run_dir / CACHE_NAME
    top = zarr.open_group(root, mode="a", zarr_format=3)
    for pair in cfg.pairs:
        for role in ROLES:
            top.require_group(f"{pair.key}/{role}")
    all_jobs = list_jobs(cfg)
    todo = [j for j in all_jobs if not _complete(root, j)]
    if todo:
        n_jobs = jobs or cfg.workers
        runner = Parallel(n_jobs=n_jobs, backend="loky", return_as="generator_unordered")
        stream = runner(delayed(_build_one)(str(root), j) for j in todo)
        for _ in tqdm(stream, total=len(todo), desc="cache", unit="frame", disable=not progress):
            pass
    return all_jobs


def _complete(root: Path, job: CacheJob) -> bool:
    try:
        group = zarr.open_group(root / job.node, mode="r", zarr_format=3)
    except (FileNotFoundError, KeyError, ValueError, zarr.errors.GroupNotFoundError):
        return False
    attrs = dict(group.attrs)
    return bool(attrs.get("done")) and attrs.get("key") == job.key


def read_frame(run_dir: Path, job: CacheJob) -> CachedFrame:
    group = zarr.open_group(run_dir / CACHE_NAME / job.node, mode="r", zarr_format=3)
    attrs: dict[str, Any] = dict(group.attrs)  # JSON values written by the caching worker
    # "target" and "inputs" are arrays, never subgroups: the caching worker writes them so.
    target = np.asarray(cast(zarr.Array, group["target"])[:]) if "target" in group else None
    classes = np.asarray(cast(zarr.Array, group["classes"])[:]) if "classes" in group else None
    return CachedFrame(
        pair=job.pair,
        role=job.role,
        frame=job.frame,
        inputs=np.asarray(cast(zarr.Array, group["inputs"])[:]),
        target=target,
        labelled=bool(attrs["labelled"]),
        extinction_per_m=float(attrs["extinction_per_m"]),
        sensor=str(attrs["sensor"]),
        classes=classes,
    )


def cache_fingerprint(run_dir: Path, jobs: Iterable[CacheJob]) -> str:
    """sha256 hex digest naming the cached frames of `jobs`, in order (the order a pass
    streams them, which the float sums depend on).

    Per frame: its node, its job key (what decides its content, FEATURE_VERSION included)
    and the mtime_ns of its `zarr.json`, which is rewritten whenever the frame is rebuilt,
    so a frame remade by other code under the same key still changes the digest. One stat
    per frame and no array read: a few milliseconds per thousand frames.

    Raises:
        TrainingError: a frame of `jobs` is not in the cache.
    """
    digest = hashlib.sha256()
    for job in jobs:
        meta = run_dir / CACHE_NAME / job.node / "zarr.json"
        try:
            written = meta.stat().st_mtime_ns
        except OSError:
            raise TrainingError(
                f"{meta}: cached frame missing (deleted while training started?); start "
                "again and the cache rebuilds it."
            ) from None
        digest.update(json.dumps([job.node, job.key, written]).encode())
        digest.update(b"\n")
    return digest.hexdigest()


def iter_frames(run_dir: Path, jobs: Iterable[CacheJob]) -> Iterator[CachedFrame]:
    """The cached frames of `jobs`, in order, each read from zarr only when asked for (one
    frame in memory at a time, for passes over a whole cache)."""
    for job in jobs:
        yield read_frame(run_dir, job)
