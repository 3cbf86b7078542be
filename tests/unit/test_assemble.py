"""The compiled assembly of weather results: the same bytes as the plain numpy rules."""

from __future__ import annotations

import numpy as np
import pytest

from lads.physics.beams import assemble, assemble_dual, prepare_beams
from lads.physics.result import Outcome
from lads.sensors.profile import load_profile


def _frame(profile_name: str, n: int = 5000, seed: int = 0):
    profile = load_profile(profile_name)
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(n, 3)).astype(np.float32) * 20
    top = profile.intensity.max_value
    intensity = profile.intensity.from_reflectivity(
        rng.random(n) * top / profile.intensity.reflectivity_full_scale
    )
    beams = prepare_beams(xyz, intensity, profile)
    outcome = rng.integers(0, 4, n).astype(np.uint8)
    range_m = beams.range_m * rng.uniform(0.3, 1.0, n)
    # Half-step values, zeros, negatives and far beyond the top level: the rounding edges.
    reflectivity = np.concatenate(
        [
            rng.random(n // 2) * 3.0,
            (np.arange(n - n // 2) % 300 + 0.5)
            * profile.intensity.step
            / profile.intensity.reflectivity_full_scale
            - 0.02,
        ]
    )
    return profile, beams, outcome, range_m, reflectivity


def _expected(profile, beams, outcome, range_m, reflectivity):
    """The rules spelled out in numpy: surviving beams in order, moved along the ray unless
    KEPT or unchanged, intensity encoded unless KEPT."""
    keep = np.flatnonzero(outcome != Outcome.LOST)
    moved = (outcome[keep] != Outcome.KEPT) & (range_m[keep] != beams.range_m[keep])
    ratio = np.where(moved, range_m[keep] / beams.range_m[keep], 1.0)
    xyz = np.where(
        moved[:, None], (beams.xyz[keep] * ratio[:, None]).astype(np.float32), beams.xyz[keep]
    )
    intensity = beams.intensity[keep].copy()
    enc = outcome[keep] != Outcome.KEPT
    intensity[enc] = profile.intensity.from_reflectivity(reflectivity[keep][enc])
    return keep, xyz, intensity


@pytest.mark.parametrize("profile_name", ["hdl64e", "hdl32e", "wads64"])
def test_single_assembly_matches_the_numpy_rules_bit_for_bit(profile_name):
    profile, beams, outcome, range_m, reflectivity = _frame(profile_name)
    res = assemble(
        beams,
        profile,
        outcome=outcome,
        range_m=range_m,
        reflectivity=reflectivity,
        extinction_per_m=0.01,
        detection_threshold=1e-5,
    )
    keep, xyz, intensity = _expected(profile, beams, outcome, range_m, reflectivity)
    assert np.array_equal(res.source_index, keep)
    assert np.array_equal(res.outcome, outcome[keep])
    assert np.array_equal(res.xyz.view(np.uint32), xyz.view(np.uint32))
    assert np.array_equal(res.intensity.view(np.uint32), intensity.view(np.uint32))
    assert np.array_equal(res.lost_index, np.flatnonzero(outcome == Outcome.LOST))


def test_dual_assembly_interleaves_the_two_single_assemblies():
    profile, beams, first, range1, refl1 = _frame("hdl64e", seed=1)
    _, _, second, range2, refl2 = _frame("hdl64e", seed=2)
    second[second == Outcome.KEPT] = Outcome.LOST  # a second return is never the input's
    common = {"extinction_per_m": 0.01, "detection_threshold": 1e-5}
    res = assemble_dual(
        beams, profile, first=(first, range1, refl1), second=(second, range2, refl2), **common
    )
    a = assemble(beams, profile, outcome=first, range_m=range1, reflectivity=refl1, **common)
    b = assemble(beams, profile, outcome=second, range_m=range2, reflectivity=refl2, **common)
    order = np.argsort(np.concatenate([a.source_index, b.source_index]), kind="stable")
    for field in ("xyz", "intensity", "source_index", "outcome"):
        merged = np.concatenate([getattr(a, field), getattr(b, field)])[order]
        assert np.array_equal(getattr(res, field), merged), field
    assert np.array_equal(res.lost_index, a.lost_index)
    assert (
        res.second_returns
        == b.source_index.size - np.setdiff1d(b.source_index, a.source_index).size
    )
