"""The networks of the intensity transfer: generators and patch discriminators (PyTorch).

PICGAN's layout (docs/physics.md §10.5) scaled for CPU inference, with the authors' flaws fixed:

- Inputs are the *raw* range-image channels of `lads.intensity.features`; each network
  z-scores them with statistics held as buffers, so they travel inside every checkpoint and
  cannot go stale (docs/physics.md §10.7 item 6).
- The intensity head is linear in z-space of ln(reflectivity + floor) and has no tanh: after
  decoding it reaches every value the target encoding can hold, retro-reflectors included
  (item 1). A linear path from the inputs to the head carries the physics (ln I_P, per-row
  gain); the convolutional path adds what physics leaves out.
- Azimuth wraps around (circular padding along W); elevation does not (zero padding).
- No normalisation layers: empty pixels would leak into InstanceNorm statistics.

A generator's cost is dominated by its full-resolution layers. Inference runs with
channels-last weights (`checkpoint.load_model`); the whole stage, features included, is timed
per 64 x 2048 frame on one core by benchmarks/intensity_speed.py.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import cast

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from lads.intensity.features import STYLES
from lads.intensity.layers import (
    LEAK,
    Normaliser,
    ResidualBlock,
    WrapConv,
    material_rows,
    material_table,
    with_materials,
)


class Generator(nn.Module):
    """Small U-Net on a range image: C raw channels in, one map out (B, 1, H, W).

    H and W must be divisible by 4. `base` sets the width (base, 2 base, 4 base channels at
    full, 1/2 and 1/4 resolution).

    With `materials` > 0 and a "material" channel (1 + material index, 0 empty), that channel
    is replaced by a learned `material_dims`-vector per material before the convolutions and
    the linear path: a per-material response the scalar reflectance cannot express. The
    table starts at zero, so a material never seen in training adds nothing and the model
    answers from its physics channels alone.
    """

    kept: torch.Tensor  # buffer, registered when the generator has materials

    def __init__(
        self,
        channels: Sequence[str],
        normalised: Sequence[str],
        *,
        base: int = 16,
        blocks: int = 3,
        materials: int = 0,
        material_dims: int = 4,
    ) -> None:
        super().__init__()
        self.channels = tuple(channels)
        self.norm = Normaliser(self.channels, normalised)
        self.material_channel = (
            self.channels.index("material") if materials and "material" in self.channels else -1
        )
        c = len(self.channels)
        if self.material_channel >= 0:
            self.material_embedding = material_table(materials, material_dims)
            keep = [i for i in range(c) if i != self.material_channel]
            self.register_buffer("kept", torch.tensor(keep, dtype=torch.long), persistent=False)
            c = c - 1 + material_dims
        self.e0 = WrapConv(c, base, 3)
        self.e1 = WrapConv(base, 2 * base, 3, stride=2)
        self.e2 = WrapConv(2 * base, 4 * base, 3, stride=2)
        self.mid = nn.Sequential(*[ResidualBlock(4 * base) for _ in range(blocks)])
        self.u1 = WrapConv(4 * base + 2 * base, 2 * base, 3)
        self.u0 = WrapConv(2 * base + base, base, 3)
        self.head = nn.Conv2d(base, 1, 1)
        self.linear = nn.Conv2d(c, 1, 1)  # physics path: a linear model of the inputs
        # Both output paths start at zero, so an untrained generator outputs 0: a residual
        # model then starts as its fitted law, and that start is a candidate on validation.
        for layer in (self.head, self.linear):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(cast(torch.Tensor, layer.bias))  # Conv2d has a bias by default

    def forward(
        self, raw: torch.Tensor, mask: torch.Tensor, law: torch.Tensor | None = None
    ) -> torch.Tensor:
        """raw (B, C, H, W) float32, mask (B, 1, H, W) float32 -> (B, 1, H, W). `law` is
        not an input of the U-Net (the same call as `PointGenerator`'s)."""
        x = self.norm(raw, mask)
        if self.material_channel >= 0:
            x = self._with_materials(x, raw)
        a0 = F.leaky_relu(self.e0(x), LEAK)
        a1 = F.leaky_relu(self.e1(a0), LEAK)
        a2 = self.mid(F.leaky_relu(self.e2(a1), LEAK))
        b1 = F.interpolate(a2, scale_factor=2.0, mode="nearest")
        b1 = F.leaky_relu(self.u1(torch.cat([b1, a1], 1)), LEAK)
        b0 = F.interpolate(b1, scale_factor=2.0, mode="nearest")
        b0 = F.leaky_relu(self.u0(torch.cat([b0, a0], 1)), LEAK)
        return self.head(b0) + self.linear(x)

    def margin(self) -> int:
        """Columns of circular context `infer` adds on each side: the decoder's output at a
        column depends on inputs at most 8 * blocks + 7 columns away (3 x 3 convolutions at
        full, 1/2 and 1/4 resolution), rounded up to a multiple of 8 so the stride-2 grids
        stay aligned with the unpadded image's."""
        return 8 * len(self.mid) + 8

    def infer(
        self, raw: torch.Tensor, mask: torch.Tensor, law: torch.Tensor | None = None
    ) -> torch.Tensor:
        """The same map as `forward` (to float rounding), for inference.

        `forward` wraps azimuth inside every convolution by redoing the few seam columns
        from narrow bands, on another convolution path whose float sums change with the
        batch size. Here the input is wrapped once by `margin()` columns on each side,
        every convolution zero-pads, and the margins are cropped at the end: one path, so
        a frame's values are bit-identical alone or in a batch (the batched GPU path keeps
        CPU bytes). Same speed as `forward` on one core, within this machine's noise
        (benchmarks/results/intensity_speed.json). Widths below the margin use `forward`.
        """
        w, m = raw.shape[-1], self.margin()
        if w < m:
            return self.forward(raw, mask)
        raw = torch.cat([raw[..., w - m :], raw, raw[..., :m]], -1)
        mask = torch.cat([mask[..., w - m :], mask, mask[..., :m]], -1)
        x = self.norm(raw, mask)
        if self.material_channel >= 0:
            x = self._with_materials(x, raw)

        def conv(layer: WrapConv, t: torch.Tensor) -> torch.Tensor:
            c = layer.conv
            return F.conv2d(t, c.weight, c.bias, c.stride, (layer.pad, layer.pad))

        a0 = F.leaky_relu(conv(self.e0, x), LEAK)
        a1 = F.leaky_relu(conv(self.e1, a0), LEAK)
        a2 = F.leaky_relu(conv(self.e2, a1), LEAK)
        for block in cast("Iterable[ResidualBlock]", self.mid):  # mid holds residual blocks only
            a2 = a2 + conv(block.b, F.leaky_relu(conv(block.a, a2), LEAK))
        b1 = F.interpolate(a2, scale_factor=2.0, mode="nearest")
        b1 = F.leaky_relu(conv(self.u1, torch.cat([b1, a1], 1)), LEAK)
        b0 = F.interpolate(b1, scale_factor=2.0, mode="nearest")
        b0 = F.leaky_relu(conv(self.u0, torch.cat([b0, a0], 1)), LEAK)
        out = self.head(b0) + self.linear(x)
        return out[..., m : m + w]

    def _with_materials(self, x: torch.Tensor, raw: torch.Tensor) -> torch.Tensor:
        return with_materials(
            x, raw, self.material_embedding.weight, self.material_channel, self.kept
        )


# The channels a pointwise generator reads (styles too, when present). The others (I_P,
# I_P per unit reflectance, literature reflectance, the mask) are functions of these or
# constant on a point; the law's value comes in beside them.
POINT_INPUTS: tuple[str, ...] = ("ln_range", "cos_incidence", "elevation", "particle")
# z-scored inputs are clamped to this many standard deviations: an MLP extrapolates linearly,
# and ego-body returns at a few centimetres sit far outside the ranges it learnt on.
POINT_INPUT_CLAMP = 4.0
# Points per matrix product in `PointGenerator.infer`: small enough that a chunk's hidden
# activations stay in a core's cache.
INFER_CHUNK = 8192


class PointGenerator(nn.Module):
    """An MLP on each pixel's (or point's) own inputs: the POINT_INPUTS channels (and the
    weather style), the material, and the fitted law's value in z-space in, one value out,
    (B, C, H, W) -> (B, 1, H, W), as 1 x 1 convolutions.

    It sees no neighbour: what it learns is a function of a point's material, range,
    incidence, laser elevation and the law there, the interactions a multiplicative law
    leaves out (a material's own range or incidence response). Trained on the few places of
    a training split, a U-Net also learns those places' layouts, which do not carry to new
    places; a per-point function does, and it gives every point of a frame its own value
    (no pixel sharing). `width` hidden units in `layers` hidden layers; the output layer
    starts at zero, so an untrained model outputs 0 (the law alone). Materials as in
    `Generator` (a learned vector per material, zero at the start). With `law_input` False
    the law's value is not an input: the correction depends on material and geometry only.
    """

    picked: torch.Tensor  # buffer: indices of the channels the MLP reads

    def __init__(
        self,
        channels: Sequence[str],
        normalised: Sequence[str],
        *,
        width: int = 32,
        layers: int = 2,
        materials: int = 0,
        material_dims: int = 4,
        law_input: bool = True,
    ) -> None:
        super().__init__()
        self.channels = tuple(channels)
        self.norm = Normaliser(self.channels, normalised)
        self.law_input = law_input
        picked = [
            i for i, name in enumerate(self.channels) if name in POINT_INPUTS or name in STYLES
        ]
        self.register_buffer("picked", torch.tensor(picked, dtype=torch.long), persistent=False)
        self.material_channel = self.channels.index("material") if materials else -1
        c = len(picked) + int(law_input)  # the law's z as one more input
        if self.material_channel >= 0:
            self.material_embedding = material_table(materials, material_dims)
            c += material_dims
        sizes = [c] + [width] * layers
        self.hidden = nn.ModuleList(
            nn.Conv2d(a, b, 1) for a, b in zip(sizes[:-1], sizes[1:], strict=True)
        )
        self.out = nn.Conv2d(sizes[-1], 1, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(cast(torch.Tensor, self.out.bias))  # Conv2d has a bias by default

    @property
    def reads(self) -> tuple[str, ...]:
        """The input channels the MLP reads (the others may be left 0)."""
        picked = [self.channels[i] for i in self.picked.tolist()]
        return tuple(picked + (["material"] if self.material_channel >= 0 else []))

    def forward(
        self, raw: torch.Tensor, mask: torch.Tensor | None, law: torch.Tensor | None = None
    ) -> torch.Tensor:
        """raw (B, C, H, W), mask (B, 1, H, W) (None: every pixel occupied), law (B, 1, H, W)
        z-space (None: 0)."""
        return self._mlp(self._inputs(raw, mask, law)).permute(0, 3, 1, 2)

    def infer(
        self, raw: torch.Tensor, mask: torch.Tensor | None, law: torch.Tensor | None = None
    ) -> torch.Tensor:
        """`forward` for inference: the points go through the MLP INFER_CHUNK at a time.

        A chunk's hidden activations stay in the CPU's cache (a whole frame's do not), which
        makes the pass faster on one core (benchmarks/intensity_speed.py). A point's value
        depends only on its own inputs and the fixed chunking of its own frame, never on
        other frames.
        """
        flat = self._point_rows(raw, mask, law)
        if flat is None:
            x = self._inputs(raw, mask, law)
            flat = x.reshape(-1, x.shape[-1])
        chunks = [self._mlp(flat[i : i + INFER_CHUNK]) for i in range(0, len(flat), INFER_CHUNK)]
        out = torch.cat(chunks) if chunks else flat.new_zeros((0, 1))  # a frame without points
        b, _, h, w = raw.shape
        return out.reshape(b, h, w, 1).permute(0, 3, 1, 2)

    def _point_rows(
        self, raw: torch.Tensor, mask: torch.Tensor | None, law: torch.Tensor | None
    ) -> torch.Tensor | None:
        """`_inputs` as (N, C_in) rows from one compiled pass (`lads.intensity.point_inputs`,
        the same bits) for one CPU frame without a mask; None otherwise."""
        if raw.device.type != "cpu" or raw.shape[0] != 1 or mask is not None:
            return None
        from lads.intensity.point_inputs import input_rows

        norm = self.norm
        mean = torch.where(norm.active, norm.mean, torch.zeros_like(norm.mean))[self.picked]
        std = torch.where(norm.active, norm.std, torch.ones_like(norm.std))[self.picked]
        has_table = self.material_channel >= 0
        table = self.material_embedding.weight if has_table else raw.new_zeros((1, 1))
        rows = input_rows(
            np.ascontiguousarray(raw.detach()[0].reshape(raw.shape[1], -1).float().numpy()),
            self.picked.numpy(),
            mean.float().numpy(),
            std.float().numpy(),
            POINT_INPUT_CLAMP,
            None if law is None else np.ascontiguousarray(law.detach().reshape(-1).float().numpy()),
            self.law_input,
            self.material_channel,
            np.ascontiguousarray(table.detach().float().numpy()),
        )
        return torch.from_numpy(rows)

    def _inputs(
        self, raw: torch.Tensor, mask: torch.Tensor | None, law: torch.Tensor | None
    ) -> torch.Tensor:
        """(B, H, W, C_in) contiguous, the MLP's inputs channels last: the picked z-scored
        channels, the law's z and the material vector."""
        x = self.norm(raw, mask, self.picked).clamp(-POINT_INPUT_CLAMP, POINT_INPUT_CLAMP)
        parts = [x.permute(0, 2, 3, 1)]
        if self.law_input:
            if law is None:
                law = raw.new_zeros((raw.shape[0], 1, *raw.shape[2:]))
            parts.append((law if mask is None else law * mask).permute(0, 2, 3, 1))
        if self.material_channel >= 0:
            parts.append(material_rows(raw, self.material_embedding.weight, self.material_channel))
        # Channels last, written once: each 1 x 1 convolution is then one matrix product over
        # all points, several times faster on a CPU than conv2d on a (1, C, N, 1) image.
        return torch.cat(parts, 3)

    def _mlp(self, x: torch.Tensor) -> torch.Tensor:
        """(..., C_in) -> (..., 1)."""
        for layer in cast("Iterable[nn.Conv2d]", self.hidden):  # hidden holds Conv2d only
            x = F.leaky_relu_(F.linear(x, layer.weight[:, :, 0, 0], layer.bias), LEAK)
        return F.linear(x, self.out.weight[:, :, 0, 0], self.out.bias)


class Discriminator(nn.Module):
    """PatchGAN critic (LSGAN, raw scores): C raw channels -> (B, 1, H/4, W/4) patch map.

    Conditioned on geometry: its inputs are the physics channels plus the intensity (or
    reflectance) being judged, so it rejects an intensity that is implausible *for that
    range, incidence and material*, not only an implausible histogram.
    """

    def __init__(self, channels: Sequence[str], normalised: Sequence[str], base: int = 16):
        super().__init__()
        self.channels = tuple(channels)
        self.norm = Normaliser(self.channels, normalised)
        c = len(self.channels)
        self.layers = nn.ModuleList(
            [
                WrapConv(c, base, 4, stride=2),
                WrapConv(base, 2 * base, 4, stride=2),
                WrapConv(2 * base, 4 * base, 3),
            ]
        )
        self.out = WrapConv(4 * base, 1, 3)

    def forward(self, raw: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x = self.norm(raw, mask)
        for layer in self.layers:
            x = F.leaky_relu(layer(x), LEAK)
        return self.out(x)

    @staticmethod
    def patch_mask(mask: torch.Tensor) -> torch.Tensor:
        """(B, 1, H, W) occupancy -> (B, 1, H/4, W/4) weights: patches at least 1/4 occupied.

        Every adversarial loss is averaged over these only, so empty sky and the occupancy
        pattern of a sensor cannot be what the critic learns (docs/physics.md §10.7 item 2).
        """
        frac = F.avg_pool2d(mask, 4)
        return (frac >= 0.25).float()


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def make_generator(
    architecture: str,
    channels: Sequence[str],
    normalised: Sequence[str],
    *,
    size: int,
    depth: int,
    materials: int,
    material_dims: int,
    law_input: bool = True,
) -> Generator | PointGenerator:
    """An untrained generator: "pointwise" (size = hidden width, depth = hidden layers;
    `law_input` whether it reads the law) or "unet" (size = base width, depth = residual
    blocks). The caller checks the name."""
    if architecture == "pointwise":
        return PointGenerator(
            channels,
            normalised,
            width=size,
            layers=depth,
            materials=materials,
            material_dims=material_dims,
            law_input=law_input,
        )
    return Generator(
        channels,
        normalised,
        base=size,
        blocks=depth,
        materials=materials,
        material_dims=material_dims,
    )
