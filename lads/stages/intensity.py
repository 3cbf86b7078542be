"""The intensity stage: a learned generator replaces every point's intensity.

It runs after the weather stage (when there is one) and changes nothing but the intensity
column: geometry, point order, labels and provenance pass through. The prediction uses the
physics modalities only (range, incidence, material from the labels, the weather's
extinction), never the input intensity, so it works the same on simulated and real frames.

Sensor models write the target sensor's encoding (KITTI remission at 0.01 steps, nuScenes
integers 0-255) whatever the source format; weather models write the frame's own sensor
encoding, moved there from the weather recording's units by the model's calibration.
Points at zero range (within `MIN_RANGE_M` of the origin: placeholders with no direction)
get intensity 0; every other point, ego-body and near-field returns included, gets a
prediction. The frame must be a scan of its reader's sensor, judged leniently
(`lads.sensors.conformity`).

Deterministic on CPU (no randomness is drawn; the rng argument is unused). On a GPU,
cuDNN convolutions may differ in the last bits, which can flip a quantisation step.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lads.config import StageConfig
from lads.errors import ConfigError, LadsError, StageError
from lads.files import sha256_file
from lads.frame import Frame
from lads.physics.projection import MIN_RANGE_M, checked_xyz
from lads.sensors.profile import load_profile

if TYPE_CHECKING:  # torch is imported only where a learned stage runs (start-up time)
    from lads.intensity.checkpoint import IntensityModel
    from lads.intensity.predict import PointRequest

# Bump when the stage's output bytes change for the same input and weights.
# 2: one azimuth wrap per pass (float rounding), batch-invariant; 3: the neighbour fallback's
# plane fit in closed form (its |cos| moves by ~1e-13, which can move a float32 step).
INTENSITY_STAGE_VERSION = "3"


@functools.lru_cache(maxsize=8)
def _weights_hash(path: str) -> str:
    return sha256_file(Path(path))[:16]


@functools.lru_cache(maxsize=8)
def _model(name_or_path: str, device: str) -> IntensityModel:
    from lads.intensity.checkpoint import resolve_model

    return resolve_model(name_or_path, device=device)


@dataclass(frozen=True, slots=True)
class IntensityStage:
    """Replace intensities with a generator's prediction.

    Attributes:
        model: a shipped model name (`lads.intensity.checkpoint.SHIPPED`) or a .pt path.
        target: the model's output domain; None = its only one, or for weather models the
            style recorded by the preceding weather stage.
        device: "cpu" or "cuda".
    """

    model: str
    target: str | None = None
    device: str = "cpu"
    name: str = "intensity"
    version: str = INTENSITY_STAGE_VERSION

    @classmethod
    def from_config(cls, config: StageConfig) -> IntensityStage:
        params = dict(config.params)
        unknown = sorted(set(params) - {"model", "target", "device"})
        if unknown or "model" not in params:
            raise ConfigError(
                f"intensity stage: parameters {sorted(params)}; expected 'model' and optionally "
                "'target' and 'device'."
            )
        stage = cls(**params)
        model = _model(stage.model, stage.device)  # missing or bad weights fail here, early
        # The weights are part of the stage's identity: the manifest records their hash.
        return replace(stage, version=f"{INTENSITY_STAGE_VERSION}+{_weights_hash(model.path)}")

    def __call__(self, frame: Frame, rng: np.random.Generator) -> Frame:
        return self.call_batch([frame], [rng])[0]

    def call_batch(self, frames: list[Frame], rngs: list[np.random.Generator]) -> list[Frame]:
        """The stage on several frames with one forward pass per run of equally shaped
        range images (the batched path for a GPU). Each frame's output is the one it gets
        alone; a bad frame raises StageError naming it (the runner then retries the frames
        one by one, so the others still build)."""
        from lads.intensity.predict import predict_points_batch

        requests, valids = [], []
        for frame in frames:
            request, valid = self._request(frame)
            requests.append(request)
            valids.append(valid)
        try:
            predictions = predict_points_batch(
                _model(self.model, self.device), requests, device=self.device
            )
        except LadsError as exc:
            where = frames[0].item.item_id if len(frames) == 1 else f"{len(frames)} frames"
            raise StageError(f"{where}: intensity stage ({self.model}): {exc}") from None
        out = []
        for frame, valid, prediction in zip(frames, valids, predictions, strict=True):
            points = frame.points.copy()
            if valid.all():  # the usual frame: no zero-range point, no masked write
                points[:, 3] = prediction.encoded
            else:
                points[:, 3] = 0.0
                points[valid, 3] = prediction.encoded
            out.append(replace(frame, points=points))
        return out

    def check_sensor(self, sensor: str, styles: tuple[str, ...]) -> None:
        """ConfigError, before any frame, when a weather model cannot write its output in
        `sensor`'s units: it needs a calibration of that sensor and of each style's own
        (`styles`: the weather stages before it, or the stage's target)."""
        model = _model(self.model, self.device)
        if model.meta.kind != "weather":
            return  # a sensor model writes its target's units, whatever the frame's sensor
        cal = model.meta.calibration
        for key in (self.target,) if self.target else styles:
            if key not in model.meta.targets:
                continue  # a style the model lacks fails with the model's own message
            spec = model.meta.targets[key]
            if sensor != spec.sensor and (sensor not in cal or spec.sensor not in cal):
                raise ConfigError(
                    f"intensity model '{self.model}' has no calibration for sensor "
                    f"'{sensor}' (it knows {sorted(cal)}), so it cannot write its {key} "
                    "output in that sensor's units; build with --intensity physics, or train "
                    "the model with that sensor's data."
                )

    def reads_style(self) -> bool:
        """Whether the stage takes its output style from the frame's weather (a weather
        model with no `target`): a rain, snow or fog stage must run before it."""
        return self.target is None and _model(self.model, self.device).meta.kind == "weather"

    def _request(self, frame: Frame) -> tuple[PointRequest, np.ndarray]:
        """The generator's inputs for one frame, and the (N,) mask of points it predicts
        (every point not at zero range)."""
        from lads.intensity.predict import PointRequest
        from lads.readers import label_set_for

        where = frame.item.item_id
        try:
            model = _model(self.model, self.device)
        except LadsError as exc:
            raise StageError(f"{where}: intensity stage ({self.model}): {exc}") from None
        weather = model.meta.kind == "weather"
        target = self.target
        if weather and target is None:
            style = frame.condition("style")
            if style is None:
                raise StageError(
                    f"{where}: the weather intensity model '{self.model}' needs the weather "
                    "stage before it (none recorded a style); fix the pipeline."
                )
            target = str(style)
        profile = load_profile(frame.sensor)
        try:  # the same range, and zero-range rule, as every stage's coordinate check
            xyz64, range_m = checked_xyz(frame.xyz, allow_zero=True)
        except LadsError as exc:
            raise StageError(f"{where}: intensity stage ({self.model}): {exc}") from None
        valid = range_m > MIN_RANGE_M
        # Most frames have no zero-range point: then every array goes in as it is, uncopied
        # (the float64 coordinates too, which the generator's own check would make again).
        every = bool(valid.all())

        def kept(values: np.ndarray) -> np.ndarray:
            return values if every else values[valid]

        labels = None if frame.labels is None else kept(frame.labels)
        label_set = label_set_for(frame.item.dataset) if labels is not None else None
        ring = None
        if "ring" in frame.columns:
            ring = kept(frame.points[:, frame.columns.index("ring")])
        extinction = float(frame.condition("extinction_per_m", 0.0) or 0.0)  # type: ignore[arg-type]
        request = PointRequest(
            kept(xyz64),
            profile,
            output_profile=profile if weather else None,
            target=target,
            labels=labels,
            label_set=label_set,
            ring=ring,
            outcome=kept(frame.outcome),
            extinction_per_m=extinction,
            where=where,
        )
        return request, valid
