"""Every corruption of lads.augment on every real frame of ../shared/data, read through the
project's readers, with each dataset's own sensor, labels and ring column: nothing aborts,
labels stay aligned, and the strength shows (fewer points, or moved / particle points)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lads.augment import CORRUPTIONS, Corruption
from lads.readers import get_reader, label_set_for
from lads.stages.sensor_faults import RING_COLUMN
from tests.real_trees import REAL_SOURCES


@pytest.fixture(scope="module")
def real_frames(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[str, object]]:
    base = tmp_path_factory.mktemp("augment_real")
    frames = []
    for tree, rs in REAL_SOURCES.items():
        root: Path = rs.build(base / tree)
        reader = get_reader(rs.reader, root, **rs.options)
        frames.extend((rs.reader, reader.read(item)) for item in reader.items())
    return frames


@pytest.mark.parametrize("name", list(CORRUPTIONS))
def test_heavy_corruption_runs_on_every_real_frame(shared_data, real_frames, name):
    assert len(real_frames) >= 100
    for dataset, frame in real_frames:
        labelled = frame.labels is not None and label_set_for(dataset) is not None
        if CORRUPTIONS[name].needs_labels and not labelled:
            continue
        ring = frame.columns.index(RING_COLUMN) if RING_COLUMN in frame.columns else None
        c = Corruption(name, "heavy", sensor=frame.sensor, dataset=dataset, ring_column=ring)
        out = c(frame.points, frame.labels, sample_id=frame.item.item_id)
        where = f"{name} on {frame.item.item_id}"
        assert np.isfinite(out.points).all(), where
        assert out.points.shape[1] == frame.points.shape[1], where
        if frame.labels is not None:
            assert out.labels.shape == (out.points.shape[0],), where
        changed = out.info.lost_index.size + np.count_nonzero(out.info.outcome)
        # Incomplete echo acts on vehicles only; a frame may have none.
        assert changed > 0 or frame.points.shape[0] < 200 or name == "incomplete_echo", where
