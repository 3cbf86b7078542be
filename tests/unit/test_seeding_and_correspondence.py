"""Per-item randomness comes from identity; both point-correspondence modes keep provenance."""

from __future__ import annotations

import numpy as np

from lads import correspondence
from lads.frame import Frame, Item
from lads.physics.result import Outcome
from lads.seeding import rng_for, seed_entropy


def test_rng_depends_only_on_identity():
    a = rng_for(0, "semantickitti:sequences/00/velodyne/000000.bin", "snow", "snow").random(4)
    b = rng_for(0, "semantickitti:sequences/00/velodyne/000000.bin", "snow", "snow").random(4)
    assert np.array_equal(a, b)
    others = [
        rng_for(1, "semantickitti:sequences/00/velodyne/000000.bin", "snow", "snow"),
        rng_for(0, "semantickitti:sequences/00/velodyne/000001.bin", "snow", "snow"),
        rng_for(0, "semantickitti:sequences/00/velodyne/000000.bin", "rain", "snow"),
        rng_for(0, "wads:sequences/00/velodyne/000000.bin", "snow", "snow"),
    ]
    for rng in others:
        assert not np.array_equal(rng.random(4), a)


def test_seed_entropy_is_root_seed_plus_four_words():
    entropy = seed_entropy(7, "x", "snow", "snow")
    assert entropy[0] == 7 and len(entropy) == 5 and all(0 <= w < 2**32 for w in entropy[1:])


def _frame(n=6):
    points = np.arange(n * 5, dtype=np.float32).reshape(n, 5)
    points[:, 4] = np.arange(n) % 3  # a "ring" column
    return Frame.from_source(
        Item("t", "a.bin"),
        "hdl32e",
        ("x", "y", "z", "intensity", "ring"),
        points,
        np.arange(10, 10 + n, dtype=np.uint32),
        {"orig": np.arange(n, dtype=np.int32)},
    )


def _weathered(src):
    rows = np.array([0, 2, 3, 5])
    pts = src.points[rows].copy()
    pts[:, 3] = 0.5
    outcome = np.array([Outcome.KEPT, Outcome.PARTICLE, Outcome.ATTENUATED, Outcome.KEPT], np.uint8)
    return src.select(rows, outcome=outcome, lost_rows=np.array([1, 4]), points=pts)


def test_select_composes_provenance_across_stages():
    once = _weathered(_frame())
    twice = once.select(
        np.array([1, 2]),
        outcome=np.array([Outcome.KEPT, Outcome.KEPT], np.uint8),
        lost_rows=np.array([0, 3]),
        points=once.points[[1, 2]],
    )
    assert twice.source_index.tolist() == [2, 3]
    assert twice.outcome.tolist() == [Outcome.PARTICLE, Outcome.ATTENUATED]  # never milder
    assert twice.lost_index.tolist() == [0, 1, 4, 5]
    assert twice.labels.tolist() == [12, 13]


def test_physical_mode_labels_particles_and_follows_sources():
    frame, source_index, outcome = correspondence.physical(_weathered(_frame()), particle_label=1)
    assert source_index.tolist() == [0, 2, 3, 5]
    assert frame.labels.tolist() == [10, 1, 13, 15]
    assert frame.extra_labels["orig"].tolist() == [0, 0, 3, 5]
    assert frame.points[:, 4].tolist() == [0, 2, 0, 2]  # ring follows its beam
    assert outcome.tolist() == [0, 2, 1, 0]


def test_aligned_mode_keeps_n_order_and_labels():
    src = _frame()
    frame, source_index, outcome = correspondence.aligned(src, _weathered(src))
    assert frame.points.shape == src.points.shape
    assert np.array_equal(frame.labels, src.labels)
    assert outcome.tolist() == [0, 3, 2, 1, 3, 0]
    assert np.all(frame.points[[1, 4], :4] == 0)  # lost beams at the origin, intensity 0
    assert np.array_equal(frame.points[[1, 4], 4], src.points[[1, 4], 4])  # ring kept
    assert np.array_equal(
        frame.points[[0, 5]][:, [0, 1, 2, 4]], src.points[[0, 5]][:, [0, 1, 2, 4]]
    )
    assert frame.points[[0, 2, 3, 5], 3].tolist() == [0.5] * 4  # the stage's intensities
    assert source_index.tolist() == list(range(6))


def test_outcome_counts_add_up():
    counts = correspondence.outcome_counts(6, np.array([0, 2, 1, 0], np.uint8), 2)
    assert counts == {
        "source": 6,
        "output": 4,
        "kept": 2,
        "attenuated": 1,
        "particle": 1,
        "lost": 2,
    }
