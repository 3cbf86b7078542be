"""`lads build` on Voxelscape, written by `lads synth` (no public sample exists): the output
is the source's own format and layout. The real formats: tests/realdata/test_build_datasets_real.py.
"""

from __future__ import annotations

import json
from pathlib import Path

from lads.config import find_pipeline, load_pipeline
from lads.runner import run_build
from lads.verify import verify_tree


def pipeline(source: str, variant: str, **overrides):
    overrides.setdefault("intensity", "physics")  # learned stage: test_build_intensity.py
    return load_pipeline(find_pipeline(source, variant)).with_overrides(**overrides)


def rows(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def test_voxelscape_tree_from_synth_keeps_every_label_file_aligned(tmp_path):
    from lads.synth import write_synthetic_dataset

    src = tmp_path / "voxelscape"
    write_synthetic_dataset(src, frames=2, layout="voxelscape", seed=1)
    out = tmp_path / "voxelscape_snow"
    report = run_build(
        "voxelscape", src, out, pipeline("voxelscape", "snow", rate_mm_h=10.0), seed=0
    )
    assert report.complete and report.built == 2
    for row in rows(out):
        records = {o["role"]: o["records"] for o in row["outputs"]}
        assert set(records) == {"scan", "label", "orig_labels", "orig_sublabels"}
        assert len(set(records.values())) == 1
    check = verify_tree(out, src)
    assert check.ok, check.summary_text()
