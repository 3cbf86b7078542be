"""masked_median is numpy's median of the selection, bit for bit."""

import numpy as np
import pytest

from lads.physics.masked_median import masked_median


def numpy_median(values, mask):
    return float(np.median(values[mask]))


@pytest.mark.parametrize("n", [1, 2, 3, 10, 1001, 120_000])
@pytest.mark.parametrize("seed", range(4))
def test_random_selections_match_numpy(n, seed):
    rng = np.random.default_rng(seed)
    kinds = [
        rng.random(n),  # cosines in [0, 1)
        rng.normal(0, 1e3, n),
        np.round(rng.random(n), 2),  # many ties
        rng.lognormal(0, 5, n),  # a wide, skewed span
    ]
    for values in kinds:
        for share in (1.0, 0.9, 0.5, 0.01):
            mask = rng.random(n) < share
            if not mask.any():
                continue
            got, want = masked_median(values, mask), numpy_median(values, mask)
            assert got == want or (np.isnan(got) and np.isnan(want)), (n, share, got, want)


def test_edge_cases_match_numpy():
    assert masked_median(np.full(7, 0.25), np.ones(7, bool)) == 0.25
    assert np.isnan(masked_median(np.array([0.1, np.nan, 0.3]), np.ones(3, bool)))
    assert masked_median(np.array([0.1, np.nan, 0.3]), np.array([True, False, True])) == 0.2
    assert np.isnan(masked_median(np.zeros(3), np.zeros(3, bool)))
    huge = np.array([-1.7e308, 1.7e308, 0.0, 5.0])
    assert masked_median(huge, np.ones(4, bool)) == float(np.median(huge))
    ends = np.array([0.0, 1.0, 1.0, 1.0, 0.0, 0.5])
    for mask in (np.ones(6, bool), np.array([1, 1, 0, 0, 1, 1], bool)):
        assert masked_median(ends, mask) == float(np.median(ends[mask]))
