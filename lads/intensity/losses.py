"""Masked losses of the intensity transfer. Every loss averages over occupied pixels (or
occupied patches for the critics) only, so empty pixels never enter an objective
(docs/physics.md §10.7 item 2)."""

from __future__ import annotations

import torch


def masked_l1(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean |pred - target| over pixels where mask > 0; 0 when nothing is occupied."""
    weight = mask.expand_as(pred)
    return ((pred - target).abs() * weight).sum() / weight.sum().clamp_min(1.0)


def masked_mse_to(score: torch.Tensor, value: float, patch_mask: torch.Tensor) -> torch.Tensor:
    """LSGAN term: mean (score - value)^2 over patches with patch_mask > 0."""
    weight = patch_mask.expand_as(score)
    return (((score - value) ** 2) * weight).sum() / weight.sum().clamp_min(1.0)


def balanced_l1(
    pred: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor,
    groups: torch.Tensor,
    power: float,
) -> torch.Tensor:
    """`masked_l1` with each occupied pixel weighted by n_group^-power, mean weight 1.

    `groups` (B, 1, H, W) holds a value per pixel (a material's index); pixels with
    the same value form a group of n_group pixels in the batch. power 0 is the plain pixel
    mean, 1 gives every group the same total weight. Rare bright materials (traffic signs,
    lane paint: ~0.1 % of a KITTI frame's pixels) otherwise hardly enter the mean at all.
    """
    if power == 0.0:
        return masked_l1(pred, target, mask)
    occupied = mask.expand_as(pred) > 0
    if not bool(occupied.any()):
        return torch.zeros((), dtype=pred.dtype, device=pred.device)
    # Group values are exact per-material constants; rounding only guards float noise.
    keys = torch.round(groups.expand_as(pred)[occupied] * 1e4)
    _, inverse, counts = torch.unique(keys, return_inverse=True, return_counts=True)
    weight = counts[inverse].to(pred.dtype) ** (-power)
    weight = weight / weight.mean()
    return ((pred[occupied] - target[occupied]).abs() * weight).mean()
