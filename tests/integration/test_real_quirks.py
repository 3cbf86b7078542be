"""What real scans hold and nominal sensor descriptions do not: every stage of every shipped
pipeline passes it through, never refuses the frame.

A ray-cast street for each reader's sensor gets the quirks found in real recordings:
exact zero-range placeholders, ego-body returns within 2.3 m at apparent elevations far
below the field of view (nuScenes: a quarter of the points within 3 m, down to -59 deg),
multipath returns far below the ground, points at elevations above the field of view, and
exact duplicate rows (WADS: ~40 %). No real data is read.
"""

from __future__ import annotations

import numpy as np
import pytest

from lads.config import pipeline_for, variants_for
from lads.frame import Frame, Item
from lads.physics.result import Outcome
from lads.readers import READERS
from lads.readers.poses import PoseTrack
from lads.seeding import rng_for
from lads.sensors.profile import load_profile
from lads.worker import stages_for
from tests.conftest import street_frame

CASES = [(source, variant) for source in sorted(READERS) for variant in variants_for(source)]
LABELS = {  # a plausible label of each label set: road / driveable surface
    "semantickitti": 40, "wads": 40, "voxelscape": 40, "nuscenes": 24, None: None,
}  # fmt: skip


def quirky_frame(source: str) -> tuple[Frame, dict[str, np.ndarray]]:
    reader = READERS[source]
    profile = load_profile(reader.sensor)
    xyz, intensity = street_frame(profile, azimuths=360, seed=3)
    rng = np.random.default_rng(7)
    n_ego = len(xyz) // 3
    az = rng.uniform(-np.pi, np.pi, n_ego)
    el = np.radians(rng.uniform(-59.0, -20.0, n_ego))
    r = rng.uniform(0.5, 2.3, n_ego)
    ego = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    zero = np.zeros((40, 3))
    multipath = np.array([[70.0, 10.0, -34.8], [-50.0, 3.0, -30.0], [20.0, 0.0, -20.0]])
    above = np.array([[5.0, 0.0, 4.0], [8.0, 1.0, 5.0]])  # +39 and +32 deg
    quirks = {"zero": zero, "ego": ego, "multipath": multipath, "above": above}
    parts = [xyz, *quirks.values()]
    points = np.concatenate(parts).astype(np.float32)
    inten = np.concatenate([intensity, rng.choice(intensity, len(points) - len(xyz))])
    dup = rng.choice(len(points), len(points) // 3, replace=False)
    points[dup[: len(dup) // 2]] = points[dup[len(dup) // 2 :][: len(dup) // 2]]
    columns = reader.columns
    table = np.column_stack([points, inten.astype(np.float32)])
    if "ring" in columns:
        ring = np.clip(profile.channel_of(points), 0, profile.channels - 1).astype(np.float32)
        ring[len(xyz) : len(xyz) + n_ego + 40] = rng.integers(0, 8, n_ego + 40)  # ego: low rings
        table = np.column_stack([table, ring])
    label = LABELS[reader.label_set]
    labels = None
    if label is not None:
        dtype = np.uint8 if reader.label_set == "nuscenes" else np.uint32
        labels = np.full(len(table), label, dtype=dtype)
    item = Item(source, "scan.bin", None if labels is None else "scan.label")
    return Frame.from_source(item, reader.sensor, columns, table, labels), quirks


def _driving_track() -> PoseTrack:
    """Three scans 0.1 s apart, driving 10 m/s along x and turning 5 deg/s."""
    poses = np.stack([np.eye(4)] * 3)
    for k, t in enumerate((-0.1, 0.0, 0.1)):
        a = np.radians(5.0 * t)
        poses[k, :2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        poses[k, 0, 3] = 10.0 * t
    return PoseTrack(np.array([0.0, 0.1, 0.2]), poses, 1, "test poses")


@pytest.mark.parametrize(("source", "variant"), CASES, ids=[f"{s}-{v}" for s, v in CASES])
def test_every_stage_passes_real_quirks_through(source: str, variant: str) -> None:
    frame, quirks = quirky_frame(source)
    n = frame.points.shape[0]
    zero_rows = np.flatnonzero(~frame.points[:, :3].any(axis=1))
    assert len(zero_rows) > len(quirks["zero"]) // 2  # some were overwritten by duplicates
    pipeline = pipeline_for(source, variant)
    for spec, stage in zip(pipeline.stages, stages_for(pipeline), strict=True):
        rng = rng_for(0, frame.item.item_id, variant, spec.stage)
        if getattr(stage, "needs_track", False):  # motion from poses: a reader would hand these
            frame = stage.call_track(frame, _driving_track(), rng)
        else:
            frame = stage(frame, rng)
    points = frame.points
    assert np.isfinite(points).all() and points.shape[1] == len(frame.columns)
    if frame.window:  # a sensor transfer: new beams, each naming the source return it hit
        assert (frame.outcome == Outcome.RESAMPLED).all() and frame.source_index.max() < n
    else:
        assert len(frame.source_index) + len(frame.lost_index) == n  # every source row counted
    # a zero-range placeholder stays one (at the origin) or is lost; it never becomes a return
    from_zero = np.isin(frame.source_index, zero_rows)
    assert not points[from_zero, :3].any()
    if frame.labels is not None:
        assert len(frame.labels) == len(points)
