"""Edge distances along the rings (`lads.diagnose.data.edges`), the feature C8 is fitted on."""

from __future__ import annotations

import math

import numpy as np

from lads.diagnose.data.edges import azimuth_step_rad, edge_distance

CAP = 10.0


def ring_points(ranges_m: np.ndarray, ring: int = 0, beams: int | None = None) -> np.ndarray:
    """(K, 3) returns of one level ring, beam j at azimuth 2 pi j / beams; range 0 = no return."""
    ranges_m = np.asarray(ranges_m, dtype=np.float64)
    beams = len(ranges_m) if beams is None else beams
    az = 2.0 * math.pi * np.arange(len(ranges_m)) / beams
    xyz = np.column_stack([ranges_m * np.cos(az), ranges_m * np.sin(az), np.full(az.size, ring)])
    return xyz[ranges_m > 0]


def distances(ranges_m: np.ndarray, **kw: float) -> np.ndarray:
    """Distance per beam of one ring (NaN where there is no return)."""
    return distances_and_spans(ranges_m, **kw)[0]


def distances_and_spans(ranges_m: np.ndarray, **kw: float) -> tuple[np.ndarray, np.ndarray]:
    ranges_m = np.asarray(ranges_m, dtype=np.float64)
    xyz = ring_points(ranges_m)
    d, s = np.full(len(ranges_m), np.nan), np.full(len(ranges_m), np.nan)
    d[ranges_m > 0], s[ranges_m > 0] = edge_distance(
        xyz, np.zeros(len(xyz), np.int64), cap=CAP, **kw
    )
    return d, s


def test_distance_counts_beams_from_the_jump_both_sides_of_it_at_zero():
    ranges = np.r_[np.full(60, 10.0), np.full(60, 20.0)]  # jumps at 59|60 and 119|0
    d = distances(ranges)
    assert np.allclose(d[[59, 60, 119, 0, 57, 63, 30]], [0, 0, 0, 0, 2.0, 3.0, CAP], atol=1e-6)


def test_on_a_thinned_ring_the_edge_is_the_midpoint_of_the_gap_in_full_scan_beams():
    ranges = np.r_[np.full(60, 10.0), np.full(60, 20.0)]
    thinned = np.where(np.arange(120) % 3 == 0, ranges, 0.0)
    # The returns beside the edge lie somewhere in 57..60: one beam from its midpoint, not 0.
    d, span = distances_and_spans(thinned, step_rad=2.0 * math.pi / 120)
    assert np.allclose(d[[57, 60, 54, 66]], [1.0, 1.0, 4.0, 7.0], atol=1e-6)
    # ... and the edge may lie anywhere in the 2 beams between them: return 57 is 0-2
    # beams from it, not 1.
    assert np.allclose(span[[57, 60, 66]], 2.0, atol=1e-6)
    full_d, full_span = distances_and_spans(ranges)
    assert np.allclose(full_span[[57, 59, 60, 63]], 0.0, atol=1e-6)


def test_a_long_run_of_missing_returns_is_an_edge_but_a_single_missing_beam_is_not():
    ranges = np.full(200, 15.0)
    ranges[50] = 0.0  # one dropped beam inside a surface
    ranges[120:170] = 0.0  # sky: no returns for 50 beams
    d = distances(ranges)
    assert np.allclose(d[[119, 170, 117, 49, 51]], [0.0, 0.0, 2.0, CAP, CAP], atol=1e-6)


def test_edges_of_one_ring_do_not_reach_the_returns_of_another():
    jumpy = np.r_[np.full(100, 10.0), np.full(100, 30.0)]
    flat = np.full(200, 12.0)
    xyz = np.vstack([ring_points(jumpy, ring=0), ring_points(flat, ring=1)])
    ring = np.repeat([0, 1], 200)
    d = edge_distance(xyz, ring, cap=CAP)[0]
    assert np.allclose(d[[99, 100]], 0.0, atol=1e-6)
    assert (d[200:] == CAP).all()


def test_distances_do_not_depend_on_the_order_of_the_points():
    rng = np.random.default_rng(3)
    ranges = 10.0 + 5.0 * (rng.random(300) < 0.05).cumsum() % 3
    xyz = ring_points(ranges)
    ring = np.zeros(len(xyz), np.int64)
    perm = rng.permutation(len(xyz))
    d, span = edge_distance(xyz, ring, cap=CAP)
    assert (d < CAP).any()
    d_perm, span_perm = edge_distance(xyz[perm], ring[perm], cap=CAP)
    assert np.array_equal(d_perm, d[perm]) and np.array_equal(span_perm, span[perm])


def test_the_azimuth_step_is_found_on_full_thinned_and_half_step_jittered_rings():
    beams = 2000
    step = 2.0 * math.pi / beams
    rng = np.random.default_rng(0)
    ring = np.repeat(np.arange(8), beams)
    az = np.tile(np.arange(beams) * step, 8) + rng.normal(0.0, 0.01 * step, 8 * beams)
    assert math.isclose(azimuth_step_rad(az, ring), step, rel_tol=0.01)
    keep = rng.random(az.size) < 1.0 / 3.0
    assert math.isclose(azimuth_step_rad(az[keep], ring[keep]), step, rel_tol=0.01)
    # KITTI rings hold many gaps of half a step: the step is still the commonest gap.
    extra = rng.random(az.size) < 0.13
    az2, ring2 = np.r_[az, az[extra] + 0.5 * step], np.r_[ring, ring[extra]]
    assert math.isclose(azimuth_step_rad(az2, ring2), step, rel_tol=0.01)


def test_an_empty_or_edgeless_scan_is_all_at_the_cap():
    assert edge_distance(np.zeros((0, 3)), np.zeros(0, np.int64), cap=CAP)[0].shape == (0,)
    flat = ring_points(np.full(50, 8.0))
    d, span = edge_distance(flat, np.zeros(50, np.int64), cap=CAP)
    assert (d == CAP).all() and (span == 0.0).all()


def test_the_mixed_pixel_term_averages_over_the_span_the_edge_may_lie_in():
    from types import SimpleNamespace

    import torch

    from lads.diagnose.effects.c8_edge_mixed_pixels import edge_cover

    e0 = torch.tensor(1.2, dtype=torch.float64)
    dist = torch.tensor([0.0, 1.0, 1.0, 4.0], dtype=torch.float64)
    span = torch.tensor([0.0, 0.0, 2.0, 3.0], dtype=torch.float64)
    got = edge_cover(SimpleNamespace(edge_beams=dist, edge_span_beams=span), e0).numpy()
    want = []
    for e, w in zip(dist.numpy(), span.numpy(), strict=True):
        grid = np.linspace(max(e - w / 2, 0.0), e + w / 2, 20001)
        want.append(np.mean(np.exp(-grid / 1.2)))
    assert np.allclose(got, want, rtol=1e-4)
    # A return beside a gap is on average nearer its edge than the midpoint says.
    assert got[2] > math.exp(-1.0 / 1.2)
