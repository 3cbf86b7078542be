"""Masked losses of the intensity transfer. Every loss averages over occupied pixels (or
occupied patches for the critics) only, so empty pixels never enter an objective
(physics.md §10.7 item 2)."""

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
