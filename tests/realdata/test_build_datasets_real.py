"""`lads build` on the real source formats: the output is the source's own format and layout.

Real samples (../shared/data) are wrapped in tmp trees of symlinks by `tests.trees`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lads import provenance
from lads.config import find_pipeline, load_pipeline
from lads.physics.result import Outcome
from lads.runner import run_build
from lads.verify import verify_tree


def pipeline(source: str, variant: str, **overrides):
    overrides.setdefault("intensity", "physics")  # learned stage: test_build_intensity.py
    return load_pipeline(find_pipeline(source, variant)).with_overrides(**overrides)


def rows(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def test_nuscenes_output_loads_with_the_devkit_and_keeps_the_ring(real_tree, tmp_path):
    from nuscenes.nuscenes import NuScenes
    from nuscenes.utils.data_classes import LidarPointCloud

    src = real_tree("nuscenes")
    out = tmp_path / "nusc_snow"
    report = run_build("nuscenes", src, out, pipeline("nuscenes", "snow", rate_mm_h=10.0), seed=0)
    assert report.complete and report.built == 2
    nusc_src = NuScenes("v1.0-mini", dataroot=str(src), verbose=False)
    nusc_out = NuScenes("v1.0-mini", dataroot=str(out), verbose=False)
    assert len(nusc_out.lidarseg) == len(nusc_src.lidarseg) == 2
    for record in nusc_out.lidarseg:
        sd = nusc_out.get("sample_data", record["sample_data_token"])
        points = np.fromfile(out / sd["filename"], "<f4").reshape(-1, 5)
        labels = np.fromfile(out / record["filename"], np.uint8)
        assert labels.size == points.shape[0]
        assert LidarPointCloud.from_file(str(out / sd["filename"])).points.shape == (4, labels.size)
        index, outcome, _ = provenance.read_item(out, sd["filename"])
        source = np.fromfile(src / sd["filename"], "<f4").reshape(-1, 5)
        assert np.array_equal(points[:, 4], source[index, 4]), "ring column follows each beam"
        assert np.all(points[:, 3] == np.round(points[:, 3])) and points[:, 3].max() <= 255
        assert np.all(labels[outcome == Outcome.PARTICLE] == 0)  # nuScenes "noise"
    check = verify_tree(out, src)
    assert check.ok, check.summary_text()


def test_semantickitti_real_frames_build_and_verify(real_tree, tmp_path):
    src = real_tree("semantickitti")
    out = tmp_path / "kitti_rain"
    report = run_build("semantickitti", src, out, pipeline("semantickitti", "rain"), seed=0, jobs=2)
    assert report.complete and report.built == 3
    check = verify_tree(out, src, regenerate=1)
    assert check.ok, check.summary_text()
    assert all(r["points"]["source"] in (124_668, 124_605, 124_478) for r in rows(out))


def test_wads_snow_gets_the_wads_snow_label_and_keeps_duplicates(real_tree, tmp_path):
    src = real_tree("wads")
    physical = tmp_path / "wads_physical"
    run_build("wads", src, physical, pipeline("wads", "snow", rate_mm_h=5.0), seed=0)
    for row in rows(physical):
        scan = next(o for o in row["outputs"] if o["role"] == "scan")
        label = next(o for o in row["outputs"] if o["role"] == "label")
        labels = np.fromfile(physical / label["path"], np.uint32)
        _, outcome, _ = provenance.read_item(physical, scan["path"])
        assert np.all(labels[outcome == Outcome.PARTICLE] == 110)
    aligned = tmp_path / "wads_aligned"
    run_build("wads", src, aligned, pipeline("wads", "snow", points="aligned"), seed=0)
    for row in rows(aligned):
        assert row["points"]["output"] == row["points"]["source"]  # duplicates all kept
        for out in row["outputs"]:
            if out["role"] == "label":
                assert (aligned / out["path"]).read_bytes() == (src / out["path"]).read_bytes()


def test_radiate_fog_writes_csv_in_the_source_style(real_tree, tmp_path):
    src = real_tree("radiate")
    out = tmp_path / "radiate_fog"
    report = run_build("radiate", src, out, pipeline("radiate", "fog", visibility_m=40.0), seed=0)
    assert report.complete and report.built == 3
    for row in rows(out):
        text = (out / row["outputs"][0]["path"]).read_text().splitlines()
        assert len(text) == row["points"]["output"]
        assert all(line.count(",") == 4 for line in text[:100])
