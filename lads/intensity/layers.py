"""Building blocks of the intensity networks (lads.intensity.model): convolutions that wrap
around in azimuth, residual blocks, the input normaliser and the material embedding."""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

LEAK = 0.2


class WrapConv(nn.Module):
    """Conv2d with circular padding along azimuth (W) and zeros along elevation (H)."""

    def __init__(self, c_in: int, c_out: int, k: int, stride: int = 1) -> None:
        super().__init__()
        self.pad = (k - 1) // 2
        self.pad_w_extra = (k - 1) - 2 * self.pad  # even kernels pad one more on the right
        self.conv = nn.Conv2d(c_in, c_out, k, stride=stride)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        p, e = self.pad, self.pad_w_extra
        if e:
            x = F.pad(x, (p, p + e, 0, 0), mode="circular")
            x = F.pad(x, (0, 0, p, p + e))
            return self.conv(x)
        # Padding a whole (C, 64, 2048) map circularly copies it, which cost as much as the
        # convolutions; instead convolve with zero padding and redo only the few output
        # columns whose window wraps around, from narrow bands of the input.
        out = self._conv(x, p)
        if p == 0:
            return out
        s, width, out_w = self.conv.stride[1], x.shape[-1], out.shape[-1]
        left = -(-p // s)  # outputs 0..left-1 reach left of column 0
        right = (width - 1 - p) // s + 1  # outputs right.. reach past column W-1
        out[..., :left] = self._conv(
            torch.cat([x[..., width - p :], x[..., : s * (left - 1) + p + 1]], -1), 0
        )
        if right < out_w:
            tail = s * (out_w - 1) + p - width + 1
            out[..., right:] = self._conv(
                torch.cat([x[..., s * right - p :], x[..., :tail]], -1), 0
            )
        return out

    def _conv(self, x: torch.Tensor, pad_w: int) -> torch.Tensor:
        c = self.conv
        return F.conv2d(x, c.weight, c.bias, c.stride, (self.pad, pad_w))


class ResidualBlock(nn.Module):
    """Two wrapped 3 x 3 convolutions with a leaky ReLU between, added to the input."""

    def __init__(self, c: int) -> None:
        super().__init__()
        self.a = WrapConv(c, c, 3)
        self.b = WrapConv(c, c, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.b(F.leaky_relu(self.a(x), LEAK))


class Normaliser(nn.Module):
    """z-scores selected raw channels with stored statistics (buffers, saved with weights)."""

    # Buffers (register_buffer), declared so their type is Tensor rather than Tensor | Module.
    mean: torch.Tensor
    std: torch.Tensor
    active: torch.Tensor

    def __init__(self, channels: Sequence[str], normalised: Sequence[str]) -> None:
        super().__init__()
        self.channels = tuple(channels)
        self.register_buffer("mean", torch.zeros(len(self.channels)))
        self.register_buffer("std", torch.ones(len(self.channels)))
        flags = [name in normalised for name in self.channels]
        self.register_buffer("active", torch.tensor(flags, dtype=torch.bool))

    def set_stats(self, mean: dict[str, float], std: dict[str, float]) -> None:
        for i, name in enumerate(self.channels):
            if bool(self.active[i]):
                self.mean[i] = float(mean[name])
                self.std[i] = max(float(std[name]), 1e-6)

    def forward(
        self, raw: torch.Tensor, mask: torch.Tensor | None, picked: torch.Tensor | None = None
    ) -> torch.Tensor:
        """raw (B, C, H, W) -> z-scored where active, kept 0 on empty pixels (mask (B, 1, H,
        W); None: every pixel occupied); with `picked` (channel indices) only those
        channels, (B, len(picked), H, W)."""
        mean = torch.where(self.active, self.mean, torch.zeros_like(self.mean))
        std = torch.where(self.active, self.std, torch.ones_like(self.std))
        if picked is not None:
            raw, mean, std = raw.index_select(1, picked), mean[picked], std[picked]
        z = (raw - mean.view(1, -1, 1, 1)) / std.view(1, -1, 1, 1)
        return z if mask is None else z * mask


def with_materials(
    x: torch.Tensor, raw: torch.Tensor, table: torch.Tensor, channel: int, kept: torch.Tensor
) -> torch.Tensor:
    """x with its material channel swapped for the material embedding (0 when empty)."""
    return torch.cat([x.index_select(1, kept), material_vectors(raw, table, channel)], 1)


def material_table(materials: int, dims: int) -> nn.Embedding:
    """The learned vector of each material (row 1 + index; row 0 = empty pixel), all zero at
    the start, so a material never seen in training adds nothing."""
    table = nn.Embedding(materials + 1, dims)
    nn.init.zeros_(table.weight)
    return table


def material_rows(raw: torch.Tensor, table: torch.Tensor, channel: int) -> torch.Tensor:
    """(B, H, W, D) the table's vector of each pixel's material, raw channel `channel`."""
    index = raw[:, channel].round().long().clamp_(0, table.shape[0] - 1)
    # Row 0 (empty pixel) starts at zero and padding_idx keeps it out of every update.
    return F.embedding(index, table, padding_idx=0)


def material_vectors(raw: torch.Tensor, table: torch.Tensor, channel: int) -> torch.Tensor:
    """(B, D, H, W) the table's vector of each pixel's material, raw channel `channel`."""
    return material_rows(raw, table, channel).permute(0, 3, 1, 2)
