"""Run an intensity generator on one frame and give *every* point an intensity.

A pointwise generator (`lads.intensity.model.PointGenerator`) is evaluated at every point's
own inputs and fitted law: each point gets its own value, owner of a pixel or not.

A U-Net generator predicts one value per range-image pixel, for the point that owns it (the
nearest). Points that share a pixel with a nearer owner (41-80 % of a 64-beam scan,
depending on the width) get the owner's prediction scaled by their own physics ratio:

    ln(I_p + f) = ln(I_pixel + f) + clip(ln(I_P[p] + e) - ln(I_P[owner] + e), -L, L)

with f the target's reflectivity floor, e = PHYSICS_FLOOR and L = ln(MAX_SHARED_RATIO);
for a residual model the fitted law ln(I_law + f) at each point takes the place of
ln(I_P + e), since the law knows the sensor (fitted intercepts, range and laser response).
So a point on the same surface as its owner inherits the learned sensor response, and a
point on another material, angle or range differs from it as the physics says. The clip
keeps a grazing or zero-reflectance neighbour from pulling a value to 0 or infinity. No
point keeps its input value: the output is assembled from scratch for all N points.

The result is in the output sensor's encoding (KITTI remission at 0.01 steps, nuScenes
integers 0-255), rounded and clipped by `IntensityEncoding.from_reflectivity`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import numpy as np
import numpy.typing as npt
import torch

from lads.errors import ModelError
from lads.intensity.checkpoint import IntensityModel, TargetSpec
from lads.intensity.features import PHYSICS_FLOOR, FrameImage, frame_image
from lads.intensity.law_groups import GroupedLaw
from lads.intensity.model import PointGenerator
from lads.physics.materials import class_ids
from lads.physics.projection import RangeImage
from lads.sensors.conformity import check_scan_of
from lads.sensors.profile import SensorProfile

MAX_SHARED_RATIO = 10.0


@dataclass(frozen=True, slots=True)
class Prediction:
    """Per-point output of `predict_points`.

    Attributes:
        reflectivity: (N,) float32 predicted reflectivity in the output sensor's units
            (encoded intensity / full scale), before quantisation.
        encoded: (N,) float32 in the output sensor's intensity encoding.
        image: the frame's range image (`owner` reads it).
    """

    reflectivity: npt.NDArray[np.float32]
    encoded: npt.NDArray[np.float32]
    image: RangeImage

    @property
    def owner(self) -> npt.NDArray[np.bool_]:
        """(N,) bool, True for points that own their pixel (made when asked for: a build
        never needs it)."""
        image = self.image
        return image.index[image.row, image.col] == np.arange(image.row.size)


def predict_image(
    model: IntensityModel, fi: FrameImage, *, device: str = "cpu"
) -> npt.NDArray[np.float32]:
    """(H, W) float32 raw generator output (z-space) for one FrameImage."""
    return predict_images(model, [fi], device=device)[0]


def predict_images(
    model: IntensityModel, images: list[FrameImage], *, device: str = "cpu"
) -> list[npt.NDArray[np.float32]]:
    """(H, W) float32 raw generator output (z-space) of each FrameImage, in one forward
    pass per run of equally shaped images (a batch: many frames per pass on a GPU)."""
    for fi in images:
        if fi.channels != model.meta.channels:
            raise ModelError(
                f"{model.path}: expects channels {list(model.meta.channels)}, the frame has "
                f"{list(fi.channels)}."
            )
    out: list[npt.NDArray[np.float32]] = []
    start = 0
    while start < len(images):
        end = start + 1
        while end < len(images) and images[end].inputs.shape == images[start].inputs.shape:
            end += 1
        out.extend(_forward(model, [fi.inputs for fi in images[start:end]], device))
        start = end
    return out


def _forward(
    model: IntensityModel, inputs: list[npt.NDArray[np.float32]], device: str
) -> list[npt.NDArray[np.float32]]:
    if model.meta.architecture == "pointwise":
        raise ModelError(
            f"{model.path}: a pointwise generator predicts points (predict_points), not "
            "range images; it needs each point's fitted law."
        )
    raw = torch.from_numpy(np.ascontiguousarray(np.stack(inputs)))
    raw = raw.to(device=device, memory_format=torch.channels_last)
    k = model.meta.channels.index("mask")
    z = _single_threaded(lambda: model.generator.infer(raw, raw[:, k : k + 1]))
    values = z[:, 0].float().cpu().numpy()
    return [values[i] for i in range(len(inputs))]


def _single_threaded(run: Callable[[], torch.Tensor]) -> torch.Tensor:
    """`run()` in inference mode on one thread: CPU kernels split work by thread count,
    which changes float sums in the last bits and can flip a quantisation step; a build
    worker and `lads verify --regenerate` in the main process must produce the same bytes."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.inference_mode():
            return run()
    finally:
        torch.set_num_threads(threads)


def law_points(
    spec: TargetSpec,
    fi: FrameImage,
    extinction_per_m: float,
    labels: npt.ArrayLike | None = None,
    label_set: str | None = None,
) -> npt.NDArray[np.float64]:
    """(N,) the target's fitted law, ln(I + f), at every point of the frame (its material,
    or its class for a law keyed by class and labels of its label set; range, incidence
    and beam elevation)."""
    grouped = GroupedLaw.from_json(spec.law)  # type: ignore[arg-type]
    classes = None
    if grouped.class_label_set is not None and labels is not None and label_set is not None:
        classes = class_ids(labels, label_set)
    return grouped.ln_predict(
        fi.material,
        fi.range_m,
        fi.cos_incidence,
        extinction_per_m,
        fi.elevation_deg,
        classes,
        label_set,
    )


@dataclass(frozen=True, slots=True)
class PointRequest:
    """One frame's inputs to `predict_points` / `predict_points_batch` (see there)."""

    xyz: npt.ArrayLike
    profile: SensorProfile
    output_profile: SensorProfile | None = None
    target: str | None = None
    labels: npt.ArrayLike | None = None
    label_set: str | None = None
    ring: npt.ArrayLike | None = None
    outcome: npt.ArrayLike | None = None
    particle: npt.ArrayLike | None = None
    extinction_per_m: float = 0.0
    where: str = "frame"


@dataclass(frozen=True, slots=True)
class _Prepared:
    fi: FrameImage
    spec: TargetSpec
    out_profile: SensorProfile
    shift: float
    extinction_per_m: float
    labels: npt.ArrayLike | None = None
    label_set: str | None = None


def predict_points(
    model: IntensityModel,
    xyz: npt.ArrayLike,
    profile: SensorProfile,
    *,
    output_profile: SensorProfile | None = None,
    target: str | None = None,
    labels: npt.ArrayLike | None = None,
    label_set: str | None = None,
    ring: npt.ArrayLike | None = None,
    outcome: npt.ArrayLike | None = None,
    particle: npt.ArrayLike | None = None,
    extinction_per_m: float = 0.0,
    device: str = "cpu",
    where: str = "frame",
) -> Prediction:
    """Generated intensity for every point of one frame.

    Args:
        model: a loaded generator.
        xyz: (N, 3) coordinates in m of the frame, in `profile`'s geometry.
        profile: the frame's own sensor profile (projection rows and elevations).
        output_profile: whose encoding and units the output is in; default the target
            sensor of `target`. For weather models it may differ from the target sensor:
            the value is then moved to its units with the calibration constants.
        target: output domain of the model (None: its only one; weather: the style).
        labels, label_set: per-point classes for the material reflectance (None: unknown).
        ring: optional (N,) ring column.
        outcome, particle: optional per-point particle flags (see `frame_image`).
        extinction_per_m: alpha of the weather the frame is in, 1/m.
        device: torch device.
        where: name of the frame for error messages.

    Returns:
        Prediction for all N points.

    Raises:
        ModelError: the model lacks the target, or a calibration for the output sensor.
        InvalidPointsError: bad points, or a frame that is clearly not a scan of `profile`
            (`lads.sensors.conformity.check_scan_of`).
    """
    req = PointRequest(
        xyz,
        profile,
        output_profile,
        target,
        labels,
        label_set,
        ring,
        outcome,
        particle,
        extinction_per_m,
        where,
    )
    return predict_points_batch(model, [req], device=device)[0]


def predict_points_batch(
    model: IntensityModel, requests: list[PointRequest], *, device: str = "cpu"
) -> list[Prediction]:
    """`predict_points` for several frames with one forward pass per run of equally shaped
    range images (the batched path for a GPU; on a CPU the same code, frame by frame in
    effect). Each frame's result does not depend on the others in the batch."""
    prepared = [_prepare(model, r) for r in requests]
    if model.meta.architecture == "pointwise":
        # One forward pass per frame: stacking several frames' points re-blocks the matrix
        # products and moves the last bits of some values, so a frame's bytes would depend
        # on its batch-mates.
        return [_finish_points(model, p, device) for p in prepared]
    z_maps = predict_images(model, [p.fi for p in prepared], device=device)
    return [_finish(p, z) for p, z in zip(prepared, z_maps, strict=True)]


def _prepare(model: IntensityModel, req: PointRequest) -> _Prepared:
    """Checks, the output sensor's shift and the frame's model inputs."""
    from lads.sensors.profile import load_profile

    xyz_arr = np.asarray(req.xyz)
    check_scan_of(xyz_arr, req.profile, ring=req.ring, where=req.where)
    key, spec = model.target(req.target)
    weather = model.meta.kind == "weather"
    out_profile = req.output_profile or load_profile(spec.sensor)
    shift = 0.0
    if out_profile.name != spec.sensor:
        cal = model.meta.calibration
        if out_profile.name not in cal or spec.sensor not in cal:
            raise ModelError(
                f"{model.path}: no calibration for sensor '{out_profile.name}' (it knows "
                f"{sorted(cal)}); it cannot express its '{key}' output in that sensor's units. "
                "Train with that sensor's data or use --intensity physics."
            )
        shift = cal[out_profile.name] - cal[spec.sensor]
    fi = frame_image(
        xyz_arr,
        req.profile,
        labels=req.labels,
        label_set=req.label_set,
        ring=req.ring,
        outcome=req.outcome,
        particle=req.particle,
        style=key if weather else None,
        styles=weather,
        range_exponent=model.meta.range_exponent,
        extinction_per_m=req.extinction_per_m,
        # A pointwise generator reads a few channels: the others are not computed.
        only=model.generator.reads if isinstance(model.generator, PointGenerator) else None,
    )
    return _Prepared(fi, spec, out_profile, shift, req.extinction_per_m, req.labels, req.label_set)


def _finish_points(model: IntensityModel, p: _Prepared, device: str) -> Prediction:
    """Every point's value from the pointwise generator at its own inputs and law."""
    spec, fi = p.spec, p.fi
    ln_law = law_points(spec, fi, p.extinction_per_m, p.labels, p.label_set)
    law = ((ln_law - spec.log_mean) / spec.log_std).astype(np.float32)
    raw = torch.from_numpy(fi.point_inputs)[None, :, :, None].to(device)
    law_t = torch.from_numpy(law)[None, None, :, None].to(device)
    generator = cast(PointGenerator, model.generator)  # only pointwise models come here
    out = _single_threaded(lambda: generator.infer(raw, None, law_t) + law_t)
    refl = out[0, 0, :, 0].float().cpu().numpy().astype(np.float64)
    # max(exp(z sigma + mu) - f, 0) exp(shift), in place: the same operations, fewer copies.
    refl *= spec.log_std
    refl += spec.log_mean
    np.exp(refl, out=refl)
    refl -= spec.floor
    np.maximum(refl, 0.0, out=refl)
    if p.shift != 0.0:  # exp(0) = 1 leaves every value as it is
        refl *= np.exp(p.shift)
    refl32 = refl.astype(np.float32)
    return Prediction(refl32, p.out_profile.intensity.from_reflectivity(refl32), fi.image)


def _finish(p: _Prepared, z: npt.NDArray[np.float32]) -> Prediction:
    """Every point's value from the generator's map (owners) and the sharing rule."""
    spec, fi = p.spec, p.fi
    image = fi.image
    n = len(fi.range_m)
    owner_idx = image.index[image.row, image.col]
    owner = owner_idx == np.arange(n)
    if spec.law is not None:  # the generator predicts a correction to the fitted law
        ln_ref = law_points(spec, fi, p.extinction_per_m, p.labels, p.label_set)
        law_map = np.zeros(z.shape, dtype=np.float32)
        law_map[image.row[owner], image.col[owner]] = (ln_ref[owner] - spec.log_mean) / spec.log_std
        z = z + law_map
    else:
        ln_ref = np.log(fi.physics.astype(np.float64) + PHYSICS_FLOOR)
    ln_pixel = z[image.row, image.col].astype(np.float64) * spec.log_std + spec.log_mean
    limit = np.log(MAX_SHARED_RATIO)
    ratio = np.clip(ln_ref - ln_ref[owner_idx], -limit, limit) if n else ln_ref
    ln_value = np.where(owner, ln_pixel, ln_pixel + ratio)
    refl = np.maximum(np.exp(ln_value) - spec.floor, 0.0) * np.exp(p.shift)
    refl32 = refl.astype(np.float32)
    return Prediction(refl32, p.out_profile.intensity.from_reflectivity(refl32), image)
