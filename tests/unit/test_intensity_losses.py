"""The masked losses of the intensity transfer (lads/intensity/losses.py)."""

from __future__ import annotations

import pytest
import torch

from lads.intensity.losses import balanced_l1, masked_l1


def images(rare_error: float = 1.0):
    """One 10 x 10 image: a material of 1 pixel with error `rare_error`, one of 98 pixels
    with error 0, and one empty pixel with a huge error that must never count."""
    pred = torch.zeros(1, 1, 10, 10)
    target = torch.zeros(1, 1, 10, 10)
    mask = torch.ones(1, 1, 10, 10)
    groups = torch.full((1, 1, 10, 10), 0.2)
    groups[0, 0, 0, 0] = 1.0
    pred[0, 0, 0, 0] = rare_error
    mask[0, 0, 9, 9] = 0.0
    pred[0, 0, 9, 9] = 1e6
    return pred, target, mask, groups


def test_power_zero_is_the_plain_masked_mean():
    pred, target, mask, groups = images()
    assert balanced_l1(pred, target, mask, groups, 0.0) == masked_l1(pred, target, mask)
    assert masked_l1(pred, target, mask).item() == pytest.approx(1.0 / 99)


def test_power_one_averages_the_per_material_mean_errors():
    pred, target, mask, groups = images()
    # Material means: 1.0 (the rare one) and 0.0: their average is 0.5.
    assert balanced_l1(pred, target, mask, groups, 1.0).item() == pytest.approx(0.5)


def test_intermediate_power_weighs_a_rare_material_more_than_its_pixel_share():
    pred, target, mask, groups = images()
    plain = masked_l1(pred, target, mask).item()
    half = balanced_l1(pred, target, mask, groups, 0.5).item()
    full = balanced_l1(pred, target, mask, groups, 1.0).item()
    assert plain < half < full


def test_gradients_flow_and_empty_batches_give_zero():
    pred, target, mask, groups = images()
    pred.requires_grad_(True)
    balanced_l1(pred, target, mask, groups, 0.5).backward()
    assert pred.grad is not None and pred.grad[0, 0, 9, 9] == 0.0
    assert balanced_l1(pred, target, torch.zeros_like(mask), groups, 0.5).item() == 0.0
