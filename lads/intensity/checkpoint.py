"""Intensity model files: one generator plus everything needed to use it correctly.

A weight file is a `torch.save` dict read back with `weights_only=True` (no pickled code):

    format            "lads-intensity"
    format_version    1
    meta              JSON-able dict, see `ModelMeta`
    state_dict        the generator's tensors, normalisation statistics included

The normalisation statistics are buffers of the generator itself, and `meta` records their
hash with the feature version and channel list, so a file whose statistics, channels or
feature definition do not match is refused at load (docs/physics.md §10.7 item 6), never used.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from lads.errors import ConfigError, ModelError
from lads.files import atomic_write
from lads.intensity.features import FEATURE_VERSION, NORMALISED_CHANNELS, channel_names
from lads.intensity.model import Generator, PointGenerator, make_generator
from lads.physics.materials import material_names
from lads.resources import weights_dir

FORMAT = "lads-intensity"
MATERIAL_DIMS = 4
FORMAT_VERSION = 1

# The pretrained models shipped in lads/intensity/weights/ (made by `make train`).
SHIPPED: dict[str, str] = {
    "synth-to-kitti": "synth-to-kitti.pt",
    "synth-to-nuscenes": "synth-to-nuscenes.pt",
    "weather": "weather.pt",
}


@dataclass(frozen=True, slots=True)
class TargetSpec:
    """How the generator's output maps to one target domain's intensities.

    Attributes:
        sensor: sensor profile of the target recordings (its encoding is the output's).
        log_mean, log_std: statistics of ln(reflectivity + floor) over the target's occupied
            pixels; the generator predicts z = (ln(refl + floor) - log_mean) / log_std.
        floor: reflectivity floor (half a quantisation step of the target encoding).
        log_k: ln of the calibration constant k with refl ~ k I_P on the target data.
        law: the physics law fitted to the target's training frames
            (`lads.intensity.fitted_physics.FittedPhysics.to_json`, groups = material
            indices) when the generator predicts a correction to it (z = G + z_law); None
            when it predicts z outright.
    """

    sensor: str
    log_mean: float
    log_std: float
    floor: float
    log_k: float
    law: dict[str, Any] | None = None


@dataclass(frozen=True, slots=True)
class ModelMeta:
    """What a weight file says about itself.

    Attributes:
        name: model name (e.g. "synth-to-kitti").
        kind: "sensor" (sensor adaptation) or "weather" (one-hot weather styles).
        channels: raw input channels, in order.
        feature_version: `lads.intensity.features.FEATURE_VERSION` it was trained with.
        range_exponent: n of I_P = rho cos(theta) / R^n.
        base, blocks: generator size (U-Net width and residual blocks; pointwise: hidden
            width and hidden layers).
        architecture: "unet" or "pointwise" (`lads.intensity.train_config.ARCHITECTURES`).
        targets: output domains by key: the target name for sensor models, the weather
            style ("snow", "fog") for weather models.
        calibration: ln k per sensor profile (targets and sources), used to express a
            weather target's intensity in another sensor's units.
        stats_sha256: hash of the normalisation statistics.
        training: free-form record (config, data, seed, steps, metrics).
        materials: material names whose indices the material channel holds (index i + 1
            is materials[i]), i.e. `material_names()` at training time.
        material_dims: length of the learned per-material vector.
        law_input: a pointwise generator reads the fitted law's value (files made before
            the option say nothing: they do).
    """

    name: str
    kind: str
    channels: tuple[str, ...]
    feature_version: str
    range_exponent: float
    base: int
    blocks: int
    targets: dict[str, TargetSpec]
    calibration: dict[str, float]
    stats_sha256: str = ""
    training: dict[str, Any] = field(default_factory=dict)
    materials: tuple[str, ...] = ()
    material_dims: int = MATERIAL_DIMS
    architecture: str = "unet"
    law_input: bool = True

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["channels"] = list(self.channels)
        out["materials"] = list(self.materials)
        return out

    @classmethod
    def from_json(cls, raw: dict[str, Any], where: str) -> ModelMeta:
        try:
            targets = {k: TargetSpec(**v) for k, v in raw["targets"].items()}
            return cls(
                name=str(raw["name"]),
                kind=str(raw["kind"]),
                channels=tuple(raw["channels"]),
                feature_version=str(raw["feature_version"]),
                range_exponent=float(raw["range_exponent"]),
                base=int(raw["base"]),
                blocks=int(raw["blocks"]),
                targets=targets,
                calibration={str(k): float(v) for k, v in raw["calibration"].items()},
                stats_sha256=str(raw["stats_sha256"]),
                training=dict(raw.get("training", {})),
                # Absent in files of feature version 1, which load() refuses by version.
                materials=tuple(str(m) for m in raw.get("materials", ())),
                material_dims=int(raw.get("material_dims", MATERIAL_DIMS)),
                architecture=str(raw.get("architecture", "unet")),
                law_input=bool(raw.get("law_input", True)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(
                f"{where}: its metadata is incomplete or malformed ({exc!r}); the file is not "
                "a lads intensity model or is damaged. Re-run `make train` or restore it."
            ) from None


@dataclass(slots=True)
class IntensityModel:
    """A loaded generator with its metadata; `generator` is in eval mode."""

    meta: ModelMeta
    generator: Generator | PointGenerator
    path: str = ""

    def target(self, key: str | None) -> tuple[str, TargetSpec]:
        """The output domain `key` (None: the only one). Raises ModelError if unknown."""
        if key is None:
            if len(self.meta.targets) != 1:
                raise ModelError(
                    f"{self.path or self.meta.name}: model has targets "
                    f"{sorted(self.meta.targets)}; name the one to use."
                )
            key = next(iter(self.meta.targets))
        spec = self.meta.targets.get(key)
        if spec is None:
            raise ModelError(
                f"{self.path or self.meta.name}: no output domain {key!r}; it was trained for "
                f"{sorted(self.meta.targets)}. Train one for {key!r} (lads train) or pick "
                "another model."
            )
        return key, spec


def build_generator(meta: ModelMeta) -> Generator | PointGenerator:
    """The untrained generator of the architecture `meta` records."""
    if meta.architecture == "pointwise":
        lawless = sorted(k for k, spec in meta.targets.items() if spec.law is None)
        if lawless:
            raise ModelError(
                f"{meta.name}: a pointwise generator corrects a fitted law, but target(s) "
                f"{lawless} carry none; the file is damaged or was not made by `lads train`."
            )
    elif meta.architecture != "unet":
        raise ModelError(
            f"{meta.name}: generator architecture {meta.architecture!r} is not one this lads "
            "knows (unet, pointwise); update lads or retrain the model."
        )
    return make_generator(
        meta.architecture,
        meta.channels,
        NORMALISED_CHANNELS,
        size=meta.base,
        depth=meta.blocks,
        materials=len(meta.materials),
        material_dims=meta.material_dims,
        law_input=meta.law_input,
    )


def stats_hash(generator: Generator | PointGenerator) -> str:
    norm = generator.norm
    payload = json.dumps(
        {
            "channels": list(norm.channels),
            "mean": [round(float(v), 7) for v in norm.mean],
            "std": [round(float(v), 7) for v in norm.std],
        },
        sort_keys=True,
    )
    return hashlib.sha256(payload.encode()).hexdigest()


def save_model(path: Path, meta: ModelMeta, generator: Generator | PointGenerator) -> None:
    """Write a weight file atomically (meta's stats hash is filled in from the generator)."""
    meta_json = meta.to_json()
    meta_json["stats_sha256"] = stats_hash(generator)
    state = {k: v.detach().cpu().clone() for k, v in generator.state_dict().items()}
    blob = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "meta": json.dumps(meta_json, sort_keys=True),
        "state_dict": state,
    }
    buffer = io.BytesIO()
    torch.save(blob, buffer)
    atomic_write(Path(path), buffer.getvalue())


def checked_device(device: str) -> str:
    """The device, or ConfigError when it is "cuda" and PyTorch here has no CUDA device (or
    it is neither "cpu" nor "cuda")."""
    if device == "cpu" or (device == "cuda" and torch.cuda.is_available()):
        return device
    if device == "cuda":
        raise ConfigError(
            "--device cuda: PyTorch on this machine has no CUDA device "
            "(torch.cuda.is_available() is False); use --device cpu (the default), or a machine "
            "with a GPU and a CUDA build of torch."
        )
    raise ConfigError(f"device {device!r}: expected 'cpu' or 'cuda'.")


def load_model(path: str | Path, *, device: str = "cpu") -> IntensityModel:
    """Load and check a weight file.

    Raises:
        ModelError: missing, unreadable or corrupt file; another format or feature version;
            channels that do not match; normalisation statistics that do not match their hash.
        ConfigError: a device this machine does not have (`checked_device`).
    """
    checked_device(device)
    where = str(path)
    blob = _read_weights(Path(path), where)
    meta = _checked_meta(blob, where)
    generator = _checked_generator(meta, blob, where)
    generator.eval()
    # Channels-last weights let oneDNN run the small convolutions without reordering every
    # activation map: the forward pass of a 64 x 2048 frame takes less than half the time
    # (benchmarks/intensity_speed.py). The values are the same convolutions, in another
    # summation order (differences ~1e-6 in z).
    # Module.to takes memory_format (torch._C._nn._parse_to) but its stub overloads omit it.
    generator.to(device=device, memory_format=torch.channels_last)  # type: ignore[call-overload]
    return IntensityModel(meta=meta, generator=generator, path=where)


def _read_weights(p: Path, where: str) -> dict[str, Any]:
    """The weight file's contents, refused unless a lads intensity model of this format."""
    if not p.is_file():
        raise ModelError(
            f"{where}: intensity model file not found. Use a shipped model "
            f"({', '.join(sorted(SHIPPED))}) or train one with `lads train CONFIG`."
        )
    try:
        blob = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for damaged files
        raise ModelError(
            f"{where}: cannot read the weights ({type(exc).__name__}: {exc}); the file is "
            "damaged or not a torch file. Restore it (git checkout) or re-run `make train`."
        ) from None
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise ModelError(f"{where}: not a lads intensity model (format {FORMAT!r} expected).")
    if blob.get("format_version") != FORMAT_VERSION:
        raise ModelError(
            f"{where}: model format version {blob.get('format_version')!r}, this lads reads "
            f"{FORMAT_VERSION}; retrain with this version (lads train)."
        )
    return blob


def _checked_meta(blob: dict[str, Any], where: str) -> ModelMeta:
    """The model's metadata, refused unless its features, channels and materials are this
    lads'."""
    try:
        meta = ModelMeta.from_json(json.loads(blob["meta"]), where)
    except (KeyError, TypeError, json.JSONDecodeError):
        raise ModelError(f"{where}: metadata missing or not JSON; the file is damaged.") from None
    if meta.feature_version != FEATURE_VERSION:
        raise ModelError(
            f"{where}: trained on input features v{meta.feature_version}, this lads computes "
            f"v{FEATURE_VERSION}; retrain it (lads train)."
        )
    expected = channel_names(meta.kind == "weather")
    if meta.channels != expected:
        raise ModelError(
            f"{where}: input channels {list(meta.channels)} do not match this lads "
            f"({list(expected)}); retrain it (lads train)."
        )
    if meta.materials != material_names():
        raise ModelError(
            f"{where}: trained with the materials {list(meta.materials)}, this lads has "
            f"{list(material_names())} (lads/physics/materials.yaml); its material indices "
            "would name other materials. Retrain it (lads train) or restore materials.yaml."
        )
    return meta


def _checked_generator(
    meta: ModelMeta, blob: dict[str, Any], where: str
) -> Generator | PointGenerator:
    """The generator of `meta` with the file's weights, refused unless they fit, match their
    statistics hash and are finite."""
    try:
        generator = build_generator(meta)
    except ModelError as exc:
        raise ModelError(f"{where}: {exc}") from None
    try:
        generator.load_state_dict(blob["state_dict"])
    except (KeyError, RuntimeError) as exc:
        raise ModelError(f"{where}: weights do not fit the recorded architecture: {exc}") from None
    if stats_hash(generator) != meta.stats_sha256:
        raise ModelError(
            f"{where}: normalisation statistics do not match the hash in its metadata; the "
            "file was altered. Restore it or retrain."
        )
    for name, tensor in generator.state_dict().items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ModelError(f"{where}: tensor {name} holds NaN or inf; the weights are corrupt.")
    return generator


def shipped_path(name: str) -> Path:
    """Path of a shipped model inside the installed package."""
    try:
        filename = SHIPPED[name]
    except KeyError:
        raise ModelError(
            f"no shipped intensity model {name!r}; shipped: {', '.join(sorted(SHIPPED))}, "
            "or pass a path to a .pt file."
        ) from None
    return weights_dir() / filename


def resolve_model(name_or_path: str, *, device: str = "cpu") -> IntensityModel:
    """A shipped model by name, or a weight file by path."""
    if name_or_path in SHIPPED:
        return load_model(shipped_path(name_or_path), device=device)
    return load_model(name_or_path, device=device)
