"""Score intensity methods on held-out real frames: paired errors, distributions, baselines.

Pure computation on frames the caller has loaded (`eval_report` writes the reports). A
*method* maps an `EvalFrame` to (N,) predicted intensity in the frame profile's encoding;
the learned generator is one, wrapped by the caller; the baselines are fitted on the target
domain's training frames in `lads.intensity.baselines`.

Metrics are computed on every point of a frame, per frame and pooled over frames (pooled
= the same metric on the concatenated points, so big frames weigh more):

    paired         MAE (encoding and reflectivity units), Pearson r, Spearman rho, mean
                   predicted / mean real per class (classes with >= 50 points)
    distributional Wasserstein-1 (reflectivity units) and the KS statistic per cell of
                   class x range bin x incidence bin, averaged over cells with >= 30
                   points weighted by point count; and both on all points at once
    retro contrast mean intensity of retro-reflective classes (materials.yaml
                   `retroreflective_sheeting`) / mean of all other points

Reflectivity is encoded intensity / the profile's full scale (`IntensityEncoding`), so
reflectivity-unit numbers compare across sensors; encoded ones only within one encoding,
which is why held-out frames must share one encoding.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError, InputDataError, InvalidPointsError
from lads.intensity import targets
from lads.intensity.eval_metrics import (
    BOUND_PREFIX,
    MIN_CELL_POINTS,
    MIN_RATIO_POINTS,
    MIN_RETRO_POINTS,
    SUBJECT,
    PointContext,
    jsonable,
    metrics,
    pooled_context,
    summarise,
)
from lads.intensity.features import FrameImage, frame_image
from lads.physics.materials import (
    LABEL_SETS,
    class_ids,
    class_materials,
)
from lads.sensors.profile import SensorProfile

FloatArray = npt.NDArray[np.float32]
Method = Callable[["EvalFrame"], FloatArray]

RANGE_EDGES_M: tuple[float, ...] = (0.0, 5.0, 10.0, 20.0, 40.0, math.inf)
COS_EDGES: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)
RETRO_MATERIAL = "retroreflective_sheeting"
ALL_CLASS = "all"
# What one method scores on one frame (or pooled); NaN (None in JSON) where undefined.
METRIC_KEYS: dict[str, str] = {
    "points": "number of points N",
    "mae_encoded": "mean |pred - real|, encoding units",
    "mae_reflectivity": "mean |pred - real| / full scale, reflectivity units",
    "pearson_r": "Pearson correlation of pred and real",
    "spearman_rho": "Spearman rank correlation of pred and real",
    "class_ratio": "{class: mean pred / mean real} for classes with >= 50 points",
    "class_ratio_count": "number of classes in class_ratio",
    "class_ratio_mean_abs_log": "mean over class_ratio of |ln ratio| (0 is ideal)",
    "class_zero_share_pred": "{class: share of pred exactly 0} for the class_ratio classes",
    "class_zero_share_real": "{class: share of real exactly 0} for the same classes",
    "cell_w1_reflectivity": "point-weighted mean Wasserstein-1 over cells, reflectivity",
    "cell_ks": "point-weighted mean two-sample KS statistic over cells",
    "cells": "cells (class x range bin x incidence bin) with >= 30 points",
    "cell_coverage": "share of the points that lie in those cells",
    "global_w1_reflectivity": "Wasserstein-1 of all pred vs all real, reflectivity",
    "global_ks": "KS statistic of all pred vs all real",
    "retro_contrast_pred": "mean pred of retro-reflective classes / mean pred of the rest",
    "retro_contrast_real": "the same for the real intensity",
    "retro_contrast_ratio": "retro_contrast_pred / retro_contrast_real (1 is ideal)",
}


@dataclass(frozen=True, eq=False)
class EvalFrame:
    """One real frame with its measured intensity, as evaluation input.

    Attributes:
        name: unique name of the frame (e.g. "00/000123"), used as a key in results.
        xyz: (N, 3) float32 coordinates in m, sensor frame.
        intensity: (N,) float32 measured intensity in `profile`'s encoding.
        profile: the frame's own sensor profile (geometry and intensity encoding).
        labels: (N,) integer class labels of `label_set`, or None (unlabelled).
        label_set: material label set of `labels` (`lads.physics.materials.LABEL_SETS`).
        ring: optional (N,) ring column, 0 = lowest beam.
        particle: optional (N,) bool, True for weather particle returns (WADS label 110).
        extinction_per_m: alpha of the frame's weather in 1/m (0 in clear weather).

    Raises:
        InvalidPointsError: arrays of the wrong shape. IntensityEncodingError: intensities
        outside the encoding. ConfigError: labels without a known label set, bad alpha.
    """

    name: str
    xyz: npt.NDArray[np.floating[Any]]
    intensity: FloatArray
    profile: SensorProfile
    labels: npt.NDArray[np.integer[Any]] | None = None
    label_set: str | None = None
    ring: npt.NDArray[Any] | None = None
    particle: npt.NDArray[np.bool_] | None = None
    extinction_per_m: float = 0.0

    def __post_init__(self) -> None:
        where = f"evaluation frame '{self.name}'"
        xyz = np.asarray(self.xyz)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise InvalidPointsError(f"{where}: xyz has shape {xyz.shape}, expected (N, 3) in m.")
        n = len(xyz)
        # Normalising to arrays once spares every metric an np.asarray; the frame stays frozen.
        object.__setattr__(self, "xyz", xyz)
        intensity = np.asarray(self.intensity, dtype=np.float32)
        object.__setattr__(self, "intensity", intensity)
        for name in ("intensity", "labels", "ring", "particle"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value)
            if arr.shape != (n,):
                raise InvalidPointsError(
                    f"{where}: {name} has shape {arr.shape}, expected ({n},) like xyz."
                )
            object.__setattr__(self, name, arr)
        self.profile.intensity.validate(intensity, f"{where}: intensity")
        if self.labels is not None and self.label_set not in LABEL_SETS:
            raise ConfigError(
                f"{where}: labels need a label_set, one of {', '.join(LABEL_SETS)}; got "
                f"{self.label_set!r}. Pass the dataset's label set or labels=None."
            )
        if not (math.isfinite(self.extinction_per_m) and self.extinction_per_m >= 0):
            raise ConfigError(
                f"{where}: extinction_per_m = {self.extinction_per_m}; expected a finite "
                "value >= 0 in 1/m."
            )

    @property
    def n_points(self) -> int:
        return len(self.xyz)


def retro_classes(label_set: str) -> frozenset[int]:
    """Class ids of `label_set` whose material is retro-reflective sheeting (materials.yaml)."""
    return frozenset(
        cid
        for cid, (_, material) in class_materials(label_set).items()
        if material == RETRO_MATERIAL
    )


def physics_image(frame: EvalFrame, range_exponent: float = 1.0) -> FrameImage:
    """`lads.intensity.features.frame_image` of a frame (per-point I_P, cos, rho, range)."""
    return frame_image(
        frame.xyz,
        frame.profile,
        labels=frame.labels,
        label_set=frame.label_set,
        ring=frame.ring,
        particle=frame.particle,
        range_exponent=range_exponent,
        extinction_per_m=frame.extinction_per_m,
    )


def unchanged_intensity(frame: EvalFrame, image: FrameImage | None = None) -> FloatArray:
    """(N,) float32 simulator intensity rho cos(theta) exp(-2 alpha R), frame's encoding."""
    fi = physics_image(frame) if image is None else image
    refl = fi.reflectance.astype(np.float64) * fi.cos_incidence
    if frame.extinction_per_m > 0:
        refl *= np.exp(-2.0 * frame.extinction_per_m * fi.range_m.astype(np.float64))
    return frame.profile.intensity.from_reflectivity(refl)


@dataclass(frozen=True, eq=False)
class EvalResult:
    """Metrics of every method on every held-out frame and pooled, plus the predictions.

    Attributes:
        methods: method names, in the order given.
        frame_names: held-out frame names, in order.
        per_frame: frame -> method -> metrics (keys: see `METRIC_KEYS`).
        pooled: method -> metrics on all held-out points together.
        summary: {"subject", "metrics", "beats": {metric: {baseline: bool}}, "best":
            {metric: [methods]}, "targets": [rows of `targets.check`]}; `beats` and
            `targets` are empty when there is no subject method.
        predictions: frame -> method -> (N,) float32 prediction in the frame's encoding.
        real: frame -> (N,) float32 measured intensity.
        classes: frame -> (N,) int32 index into `class_names` of every point.
        class_names: class vocabulary ("all" for unlabelled frames).
        encoding: the held-out profile's name (the units of "encoded" metrics).
    """

    methods: tuple[str, ...]
    frame_names: tuple[str, ...]
    per_frame: dict[str, dict[str, dict[str, Any]]]
    pooled: dict[str, dict[str, Any]]
    summary: dict[str, Any]
    predictions: dict[str, dict[str, FloatArray]] = field(repr=False)
    real: dict[str, FloatArray] = field(repr=False)
    classes: dict[str, npt.NDArray[np.int32]] = field(repr=False)
    class_names: tuple[str, ...] = ()
    encoding: str = ""

    def pooled_values(
        self,
    ) -> tuple[FloatArray, dict[str, FloatArray], npt.NDArray[np.int32]]:
        """(real (M,), {method: prediction (M,)}, class index (M,)) over all frames."""
        names = self.frame_names
        real = np.concatenate([self.real[f] for f in names])
        preds = {m: np.concatenate([self.predictions[f][m] for f in names]) for m in self.methods}
        return real, preds, np.concatenate([self.classes[f] for f in names])

    def to_json(self) -> dict[str, Any]:
        """JSON-able dict: floats to 6 significant digits, NaN and inf as None."""
        return jsonable(
            {
                "methods": list(self.methods),
                "frames": list(self.frame_names),
                "encoding": self.encoding,
                "definitions": {
                    "range_bin_edges_m": list(RANGE_EDGES_M[:-1]),
                    "range_bins": "[e_i, e_i+1), the last one open-ended",
                    "cos_incidence_bin_edges": list(COS_EDGES),
                    "min_cell_points": MIN_CELL_POINTS,
                    "min_class_ratio_points": MIN_RATIO_POINTS,
                    "min_retro_points": MIN_RETRO_POINTS,
                    "retro_material": RETRO_MATERIAL,
                    "w1_units": "reflectivity (encoded / full scale)",
                    "metrics": METRIC_KEYS,
                },
                "pooled": self.pooled,
                "per_frame": self.per_frame,
                "summary": self.summary,
            }
        )


def evaluate(
    heldout: Iterable[EvalFrame], methods: Mapping[str, Method], *, subject: str = SUBJECT
) -> EvalResult:
    """Run every method on every held-out frame and score it against the real intensity.

    Args:
        heldout: real frames not used for training or fitting, sharing one intensity
            encoding; every frame needs at least one point and a unique name.
        methods: name -> method; each returns (N,) finite values in the frame's encoding.
        subject: the method the summary compares with all others.

    Returns:
        EvalResult.

    Raises:
        InputDataError: no frames or methods, empty or duplicate frames, mixed encodings,
            or a method output of the wrong shape or with NaN/inf.
    """
    frames = list(heldout)
    if not frames or not methods:
        raise InputDataError(
            f"evaluate: got {len(frames)} held-out frames and {len(methods)} methods; both "
            "are needed (fit_baselines gives the baselines)."
        )
    _check_heldout(frames)
    vocabulary: dict[str, int] = {}
    contexts, per_frame, predictions = _score_frames(frames, methods, vocabulary)
    pooled_ctx = pooled_context(contexts)
    names = tuple(vocabulary)
    pooled = {
        m: metrics(pooled_ctx, np.concatenate([predictions[f.name][m] for f in frames]), names)
        for m in methods
    }
    counts = np.bincount(pooled_ctx.cls, minlength=len(names))
    summary = summarise(pooled, subject)
    summary["targets"] = targets.check(
        pooled,
        {n: int(c) for n, c in zip(names, counts, strict=True)},
        frames[0].profile.name,
        subject=subject,
        bound_prefix=BOUND_PREFIX,
    )
    return EvalResult(
        methods=tuple(methods),
        frame_names=tuple(f.name for f in frames),
        per_frame=per_frame,
        pooled=pooled,
        summary=summary,
        predictions=predictions,
        real={f.name: f.intensity for f in frames},
        classes={f.name: c.cls.astype(np.int32) for f, c in zip(frames, contexts, strict=True)},
        class_names=names,
        encoding=frames[0].profile.name,
    )


def _score_frames(
    frames: list[EvalFrame], methods: Mapping[str, Method], vocabulary: dict[str, int]
) -> tuple[
    list[PointContext], dict[str, dict[str, dict[str, Any]]], dict[str, dict[str, FloatArray]]
]:
    """Each frame's point context, every method's metrics on it (frame -> method -> metrics)
    and its checked predictions (frame -> method -> (N,) float32); classes join `vocabulary`
    in the order met."""
    contexts, per_frame, predictions = [], {}, {}
    for frame in frames:
        ctx = _context(frame, vocabulary)
        preds = {name: _checked(name, method(frame), frame) for name, method in methods.items()}
        contexts.append(ctx)
        predictions[frame.name] = preds
        names = tuple(vocabulary)
        per_frame[frame.name] = {m: metrics(ctx, p, names) for m, p in preds.items()}
    return contexts, per_frame, predictions


def _check_heldout(frames: list[EvalFrame]) -> None:
    seen: set[str] = set()
    for frame in frames:
        if frame.name in seen:
            raise InputDataError(f"evaluate: two held-out frames are named '{frame.name}'.")
        seen.add(frame.name)
        if frame.n_points == 0:
            raise InputDataError(
                f"evaluate: held-out frame '{frame.name}' has no points; leave it out."
            )
    encodings = {f.profile.intensity for f in frames}
    if len(encodings) > 1:
        raise InputDataError(
            f"evaluate: held-out frames use {len(encodings)} intensity encodings (profiles "
            f"{sorted({f.profile.name for f in frames})}); pooled metrics need one. Evaluate "
            "one target domain at a time."
        )


def _checked(name: str, values: Any, frame: EvalFrame) -> FloatArray:
    arr = np.asarray(values, dtype=np.float32)
    if arr.shape != (frame.n_points,):
        raise InputDataError(
            f"method '{name}' returned shape {arr.shape} for frame '{frame.name}'; a method "
            f"must return one intensity per point, ({frame.n_points},)."
        )
    bad = int(np.count_nonzero(~np.isfinite(arr)))
    if bad:
        raise InputDataError(
            f"method '{name}' returned {bad} NaN or infinite values for frame '{frame.name}'."
        )
    return arr


def _context(frame: EvalFrame, vocabulary: dict[str, int]) -> PointContext:
    fi = physics_image(frame)
    n = frame.n_points
    retro: npt.NDArray[np.bool_] | None = None
    if frame.labels is None or frame.label_set is None:
        cls = np.full(n, vocabulary.setdefault(ALL_CLASS, len(vocabulary)), dtype=np.int64)
    else:
        ids = class_ids(frame.labels, frame.label_set)
        known = class_materials(frame.label_set)
        uniq, inverse = np.unique(ids, return_inverse=True)
        codes = np.array(
            [
                vocabulary.setdefault(
                    known[int(c)][0] if int(c) in known else f"{frame.label_set} {int(c)}",
                    len(vocabulary),
                )
                for c in uniq
            ],
            dtype=np.int64,
        )
        cls = codes[inverse.reshape(-1)]
        retro_ids = retro_classes(frame.label_set)
        retro = np.isin(ids, list(retro_ids)) if retro_ids else None
    range_bin = np.searchsorted(np.asarray(RANGE_EDGES_M[1:-1]), fi.range_m, side="right")
    cos_bin = np.searchsorted(np.asarray(COS_EDGES[1:-1]), fi.cos_incidence, side="right")
    n_range, n_cos = len(RANGE_EDGES_M) - 1, len(COS_EDGES) - 1
    cell = (cls * n_range + range_bin) * n_cos + cos_bin
    return PointContext(
        real=frame.intensity.astype(np.float64),
        full_scale=frame.profile.intensity.reflectivity_full_scale,
        cls=cls,
        cell=cell.astype(np.int64),
        retro=retro,
    )
