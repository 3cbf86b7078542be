"""Corrupt one point cloud in memory: the transform API that data loaders call
(docs/augment.md).

`corrupt(points, labels, instance, rng, corruption=..., severity=..., sensor=...)` runs the
same stage `lads build` runs, on plain arrays: the input's columns and dtype are kept, labels
and instance ids follow each output point's source beam, and `info` says where every output
point came from. `Corruption` is the same thing configured once, for loaders: its randomness
comes from (seed, sample id, epoch), never from the worker that happens to run it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from lads.augment.pseudo_labels import PSEUDO_LABEL_SET, ground_labels
from lads.config import StageConfig
from lads.correspondence import label_fits
from lads.corruptions import CorruptionSpec, corruption_spec
from lads.errors import AugmentInputError, ConfigError
from lads.frame import RING_COLUMN, Frame, Item, not_lasers
from lads.physics.result import Outcome
from lads.physics.severity import SEVERITIES
from lads.readers.base import unusable_values
from lads.seeding import augment_rng
from lads.sensors.profile import SensorProfile, load_profile
from lads.stage_params import check_stage, resolved
from lads.stages import build_stage
from lads.stages.base import Stage

# Item.dataset of arrays that name no dataset.
ANONYMOUS_DATASET = "augment"
# Columns every input must start with, in this order.
LEADING_COLUMNS = ("x", "y", "z", "intensity")
# The stage of a sensor transfer (cross-sensor): its output beams are the target's.
SENSOR_STAGE = "sensor"
# The corruption that, given no labels, lies on the fitted ground (lads.physics.ground_fit).
GROUND_FROM_FIT = "wet_ground"


@dataclass(frozen=True, slots=True)
class AugmentInfo:
    """What one corruption did to one point cloud.

    Attributes:
        corruption: the corruption's name. severity: its preset, or None.
        params: the stage parameters it ran with (the preset's value filled in).
        sensor: the sensor profile of the output: the input's, or cross-sensor's target
            (whose intensity encoding the output's intensity column then uses).
        source_index: (M,) int64 input row of each output point (a beam's second return
            repeats its row).
        outcome: (M,) uint8 `lads.physics.result.Outcome` of each output point.
        lost_index: (K,) int64 input rows with no output point.
        n_source: N, the input's point count.
        conditions: what the stage recorded about the whole cloud (e.g. extinction_per_m,
            dead_channels).
    """

    corruption: str
    severity: str | None
    params: dict[str, Any]
    sensor: str
    source_index: npt.NDArray[np.int64]
    outcome: npt.NDArray[np.uint8]
    lost_index: npt.NDArray[np.int64]
    n_source: int
    conditions: dict[str, str | float]


class Augmented(NamedTuple):
    """`corrupt`'s result; unpacks as (points, labels, instance, info)."""

    points: npt.NDArray[np.floating[Any]]
    labels: npt.NDArray[np.generic] | None
    instance: npt.NDArray[np.generic] | None
    info: AugmentInfo


class Corruption:
    """One corruption at one strength for one sensor, configured once and applied to many
    point clouds (the object the loader adapters hold).

    Args:
        corruption: a name of `lads.augment.CORRUPTIONS` (or a peer's name for it, e.g.
            "motion_blur").
        severity: "light", "moderate" or "heavy" (`lads.physics.severity`), or None when the
            physical parameter is given in `params` (e.g. rate_mm_h=8.0).
        sensor: the sensor profile the points were recorded with (`lads profiles`); it sets
            the intensity encoding, beams and detection limit.
        dataset: the reader whose label ids `labels` holds (e.g. "semantickitti",
            "nuscenes"); wet ground and incomplete echo read their classes through it
            (without labels, wet ground lies on the fitted ground), and particle returns
            take its particle label unless `particle_label` is given.
        particle_label: label of particle (rain, snow, fog) returns, e.g. the ignore index of
            a training config; instance ids of particle returns are 0.
        ring_column: the column holding each point's laser (ring), if any; beam_missing uses
            it instead of the nearest elevation.
        seed: root seed of `__call__`'s per-sample generators.
        **params: further stage parameters (`lads.stage_params.STAGE_PARAMS`), e.g.
            mode="dual" for weather, channels=[3, 17] for beam_missing, target="hdl32e"
            for cross_sensor (required there).

    Raises:
        ConfigError: unknown corruption, severity, sensor, dataset or parameter.
    """

    def __init__(
        self,
        corruption: str,
        severity: str | None = None,
        *,
        sensor: str,
        dataset: str | None = None,
        particle_label: int | None = None,
        ring_column: int | None = None,
        seed: int = 0,
        **params: Any,
    ) -> None:
        self.spec: CorruptionSpec = corruption_spec(corruption)
        if severity is not None and not self.spec.has_presets:
            raise ConfigError(
                f"corruption {self.spec.name!r} has no severities; give its parameters "
                "(cross_sensor: target=<profile>, see `lads profiles`)."
            )
        if self.spec.stage == SENSOR_STAGE:
            # A loader has one scan, not a sequence: the transfer uses the frame alone.
            params = {"neighbours": 0, **params}
        if severity is not None and severity not in SEVERITIES:
            raise ConfigError(
                f"corruption {corruption!r}: severity {severity!r}; expected one of "
                f"{', '.join(SEVERITIES)}."
            )
        self.severity = severity
        self.profile: SensorProfile = load_profile(sensor)
        self.dataset = dataset
        self.particle_label = _particle_label(dataset, particle_label)
        self.ring_column = ring_column
        self.seed = int(seed)
        where = f"corruption {self.spec.name!r}"
        given = {**params, **({"severity": severity} if severity is not None else {})}
        self.params: dict[str, Any] = resolved(self.spec.stage, given, where)
        check_stage(self.spec.stage, self.params, where)
        self.stage: Stage = build_stage(StageConfig(self.spec.stage, self.params))
        if getattr(self.stage, "needs_track", False):
            raise ConfigError(
                f"{where}: ego_motion {self.params.get('ego_motion')!r} needs a sequence's poses, "
                "which a single cloud has not; give velocity_m_s (and angular_velocity_deg_s): "
                "lads.augment.ego_motion_from_poses makes them from your poses."
            )

    def __repr__(self) -> str:
        return (
            f"Corruption({self.spec.name!r}, severity={self.severity!r}, "
            f"sensor={self.profile.name!r}, params={self.params!r})"
        )

    def rng(self, sample_id: str | int, epoch: int = 0) -> np.random.Generator:
        """The generator of one sample in one epoch (`lads.seeding.augment_rng`)."""
        return augment_rng(self.seed, sample_id, epoch, self.spec.name)

    def __call__(
        self,
        points: npt.NDArray[np.floating[Any]],
        labels: npt.NDArray[np.generic] | None = None,
        instance: npt.NDArray[np.generic] | None = None,
        *,
        sample_id: str | int,
        epoch: int = 0,
    ) -> Augmented:
        """`apply` with the generator of (seed, sample_id, epoch)."""
        return self.apply(points, labels, instance, self.rng(sample_id, epoch), sample_id)

    def apply(
        self,
        points: npt.NDArray[np.floating[Any]],
        labels: npt.NDArray[np.generic] | None,
        instance: npt.NDArray[np.generic] | None,
        rng: np.random.Generator,
        sample_id: str | int = "",
    ) -> Augmented:
        """Corrupt one cloud with the given generator.

        Args:
            points: (N, C) float32 or float64, C >= 4: x, y, z in m (sensor frame),
                intensity in the sensor's encoding, then any further columns (kept).
            labels: optional (N,) per-point class ids (any integer dtype).
            instance: optional (N,) per-point instance ids.
            rng: the generator (see `rng`).
            sample_id: recorded in nothing but error messages.

        Returns:
            Augmented(points (M, C) of the input dtype, labels (M,) or None, instance (M,)
            or None, info).

        Raises:
            AugmentInputError: wrong shapes, dtypes, columns or intensity encoding, or
                labels without a class for particle returns.
        """
        _check_arrays(points, labels, instance, self.ring_column, self.profile, sample_id)
        if labels is None and self.spec.name == GROUND_FROM_FIT:
            return self._on_fitted_ground(points, instance, rng, sample_id)
        if labels is not None and self.spec.adds_particles and self.particle_label is None:
            raise AugmentInputError(
                f"sample {sample_id!r}: {self.spec.name} adds particle returns, but labels "
                "were given with no class for them; pass particle_label=<id> (e.g. your "
                "ignore index) or dataset=<reader name> for that dataset's particle label."
            )
        if labels is not None and self.spec.adds_particles:
            _check_label_fits(self.particle_label, labels, sample_id)
        if self.spec.needs_labels and (labels is None or self.dataset is None):
            raise AugmentInputError(
                f"sample {sample_id!r}: {self.spec.name} reads point classes: pass labels and "
                "dataset=<reader name> whose class ids they hold (e.g. 'semantickitti')."
            )
        frame = self._frame(points, labels, instance, sample_id)
        out = self.stage(frame, rng)
        return self._result(points, out)

    def _on_fitted_ground(
        self,
        points: npt.NDArray[np.floating[Any]],
        instance: npt.NDArray[np.generic] | None,
        rng: np.random.Generator,
        sample_id: str | int,
    ) -> Augmented:
        """Wet ground on a cloud without labels: the road is the fitted ground
        (`lads.augment.pseudo_labels.ground_labels`); the result has no labels either."""
        labels = ground_labels(points[:, :3])
        frame = replace(
            self._frame(points, labels, instance, sample_id),
            item=Item(dataset=PSEUDO_LABEL_SET, relpath=str(sample_id)),
        )
        out = self._result(points, self.stage(frame, rng))
        info = replace(out.info, conditions={**out.info.conditions, "ground": "fitted"})
        return Augmented(out.points, None, out.instance, info)

    def _frame(
        self,
        points: npt.NDArray[np.floating[Any]],
        labels: npt.NDArray[np.generic] | None,
        instance: npt.NDArray[np.generic] | None,
        sample_id: str | int,
    ) -> Frame:
        kept = list(range(4)) + [k for k in range(4, points.shape[1]) if self._passed(k)]
        extra = tuple(RING_COLUMN if k == self.ring_column else f"column_{k}" for k in kept[4:])
        item = Item(dataset=self.dataset or ANONYMOUS_DATASET, relpath=str(sample_id))
        values = points if len(kept) == points.shape[1] else points[:, kept]
        return Frame.from_source(
            item,
            self.profile.name,
            LEADING_COLUMNS + extra,
            np.ascontiguousarray(values, dtype=np.float32),
            labels,
            None if instance is None else {"instance": instance},
        )

    def _passed(self, column: int) -> bool:
        """Whether a further column goes through the stage: every one does, except that a
        sensor transfer takes the ring alone (the others follow the return each beam hit)."""
        return self.spec.stage != SENSOR_STAGE or column == self.ring_column

    def _result(self, points: npt.NDArray[np.floating[Any]], out: Frame) -> Augmented:
        rows = out.source_index
        if self.spec.stage == SENSOR_STAGE:
            new_points = _transferred_points(points, out, self.ring_column)
        elif points.dtype == np.float32:
            new_points = out.points
        else:
            # Keep the input's precision wherever the corruption left a value alone.
            new_points = points[rows]
            moved = out.points != new_points.astype(np.float32)
            new_points[moved] = out.points[moved]
        particle = out.outcome == Outcome.PARTICLE
        labels, instance = out.labels, out.extra_labels.get("instance")
        if particle.any():
            if labels is not None:
                labels = labels.copy()
                labels[particle] = self.particle_label
            if instance is not None:
                instance = instance.copy()
                instance[particle] = 0
        info = AugmentInfo(
            corruption=self.spec.name,
            severity=self.severity,
            params=dict(self.params),
            sensor=out.sensor,
            source_index=rows,
            outcome=out.outcome,
            lost_index=out.lost_index,
            n_source=out.n_source,
            conditions=dict(out.conditions),
        )
        return Augmented(new_points, labels, instance, info)


def corrupt(
    points: npt.NDArray[np.floating[Any]],
    labels: npt.NDArray[np.generic] | None = None,
    instance: npt.NDArray[np.generic] | None = None,
    rng: np.random.Generator | None = None,
    *,
    corruption: str,
    severity: str | None = None,
    sensor: str,
    **options: Any,
) -> Augmented:
    """Corrupt one point cloud: `Corruption(corruption, severity, sensor=sensor, **options)`
    applied with `rng`.

    Args:
        points, labels, instance: as `Corruption.apply`.
        rng: the generator; for reproducible training use
            `lads.seeding.augment_rng(seed, sample_id, epoch, corruption)`.
        corruption, severity, sensor, **options: as `Corruption`.

    Raises:
        AugmentInputError: bad arrays, or no rng. ConfigError: bad configuration.
    """
    if not isinstance(rng, np.random.Generator):
        raise AugmentInputError(
            "corrupt: pass rng=numpy.random.Generator, e.g. "
            "lads.seeding.augment_rng(seed, sample_id, epoch, corruption), so the draw is "
            "reproducible."
        )
    spec = Corruption(corruption, severity, sensor=sensor, **options)
    return spec.apply(points, labels, instance, rng)


def _transferred_points(
    points: npt.NDArray[np.floating[Any]], out: Frame, ring_column: int | None
) -> npt.NDArray[np.floating[Any]]:
    """(M, C) points of a transfer in the input's layout and dtype: x, y, z, intensity (the
    target's encoding) and ring (the target's channel) from the transfer; every further
    column the value of the source return each beam hit."""
    new = points[out.source_index]
    new[:, :4] = out.points[:, :4]
    if ring_column is not None:
        new[:, ring_column] = out.points[:, out.columns.index(RING_COLUMN)]
    return new


def _particle_label(dataset: str | None, particle_label: int | None) -> int | None:
    if dataset is None:
        return particle_label
    from lads.readers import READERS, reader_class

    if dataset not in READERS:
        raise ConfigError(f"dataset {dataset!r}; expected a reader name: {', '.join(READERS)}.")
    return int(reader_class(dataset).particle_label) if particle_label is None else particle_label


def checked_probability(value: Any, where: str) -> float:
    """`value` as the share of samples an adapter corrupts; AugmentInputError unless in
    [0, 1]."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
        raise AugmentInputError(f"{where}: probability {value!r}; expected a number in [0, 1].")
    return float(value)


def _check_label_fits(label: Any, labels: npt.NDArray[np.generic], sample_id: str | int) -> None:
    """AugmentInputError unless the particle class `label` is a value of the labels' dtype
    (`lads.correspondence.label_fits`)."""
    if label_fits(label, labels.dtype):
        return
    raise AugmentInputError(
        f"sample {sample_id!r}: particle_label {label} is not a value of the labels' dtype "
        f"{labels.dtype}; pass a class id that fits it, or labels of a wider signed dtype "
        "(e.g. int64 for an ignore index of -1)."
    )


def _check_arrays(
    points: Any,
    labels: Any,
    instance: Any,
    ring_column: int | None,
    profile: SensorProfile,
    sample_id: str | int,
) -> None:
    """Raise AugmentInputError unless the arrays fit the contract of `Corruption.apply`."""
    where = f"sample {sample_id!r}"
    if not isinstance(points, np.ndarray) or points.dtype not in (np.float32, np.float64):
        kind = type(points).__name__ + (f" of {points.dtype}" if hasattr(points, "dtype") else "")
        raise AugmentInputError(
            f"{where}: points must be a float32 or float64 numpy array, got {kind}; convert "
            "tensors with .numpy() (the adapters in lads.augment do)."
        )
    if points.ndim != 2 or points.shape[1] < 4:
        raise AugmentInputError(
            f"{where}: points have shape {points.shape}; expected (N, C) with C >= 4 columns "
            f"starting {', '.join(LEADING_COLUMNS)}."
        )
    for name, values in (("labels", labels), ("instance", instance)):
        if values is not None and (
            not isinstance(values, np.ndarray) or values.shape != (points.shape[0],)
        ):
            shape = getattr(values, "shape", type(values).__name__)
            raise AugmentInputError(
                f"{where}: {name} have shape {shape}; expected ({points.shape[0]},), one per point."
            )
    if ring_column is not None and not 4 <= ring_column < points.shape[1]:
        raise AugmentInputError(
            f"{where}: ring_column {ring_column} is not one of the further columns "
            f"4..{points.shape[1] - 1} of these points."
        )
    columns = LEADING_COLUMNS + tuple(f"column_{k}" for k in range(4, points.shape[1]))
    problem = unusable_values(points, columns)
    if problem is not None:
        raise AugmentInputError(
            f"{where}: {problem}. Drop or repair such rows before corrupting the cloud (a "
            "build reports a scan file holding them as corrupt)."
        )
    profile.intensity.validate(points[:, 3], f"{where}: points[:, 3] (intensity)")
    if ring_column is not None:
        ring = points[:, ring_column]
        bad = not_lasers(ring, profile.channels)
        if bad.any():
            raise AugmentInputError(
                f"{where}: {int(bad.sum())} ring values (column {ring_column}) are not lasers "
                f"0..{profile.channels - 1} of {profile.name} (e.g. {ring[bad][:3].tolist()}); "
                "pass the ring_column of the laser index, or the sensor the cloud is from."
            )
