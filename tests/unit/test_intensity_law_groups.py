"""A generator's law with per-class offsets on its material intercepts, for frames of the
target's label set only; the cache's class planes that feed it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lads.errors import ConfigError
from lads.intensity.cache import CachedFrame, pixel_classes
from lads.intensity.checkpoint import TargetSpec
from lads.intensity.features import channel_names, frame_image
from lads.intensity.law_groups import CLASS_PRIOR_POINTS, GroupedLaw, class_offsets
from lads.intensity.law_reference import TorchLaw, fit_law
from lads.intensity.predict import law_points
from lads.intensity.train_config import load_train_config
from lads.resources import train_configs_dir
from lads.sensors.profile import load_profile
from lads.synth import synth_frame

HDL64 = load_profile("hdl64e")
ROAD, PARKING, RIDER = 40, 44, 255  # road and parking: both asphalt in materials.yaml
BRIGHTER_PARKING = 0.8  # ln units above road


def _cached(seed: int, few_rider: bool = True) -> tuple[CachedFrame, np.ndarray]:
    """A synthetic street whose parking reads brighter than its road (same material), as
    a cached training frame with its class plane; and the frame's labels."""
    f = synth_frame("hdl64e", frames=1, seed=seed, index=0, azimuth_bins=512)
    labels = (f.labels & 0xFFFF).astype(np.uint32)
    road = np.flatnonzero(labels == ROAD)
    labels[road[::2]] = PARKING
    if few_rider:
        labels[road[1:20:2]] = RIDER  # ten riders on the road
    fi = frame_image(f.xyz, HDL64, labels=labels, label_set="semantickitti", ring=f.ring)
    rng = np.random.default_rng(seed)
    names = channel_names(False)
    occ = fi.inputs[names.index("mask")] > 0
    ln_r = fi.inputs[names.index("ln_range")]
    classes = pixel_classes(fi, labels, "semantickitti", "semantickitti")
    ln = -1.5 + 0.3 * ln_r + np.where(classes == PARKING, BRIGHTER_PARKING, 0.0)
    target = np.where(occ, np.exp(ln + rng.laplace(0, 0.03, occ.shape)), 0).astype(np.float32)
    frame = CachedFrame(
        "kitti", "target", f"f{seed}", fi.inputs, target, True, 0.0, "hdl64e", classes
    )
    return frame, labels


def test_the_class_plane_holds_each_pixels_class_only_for_the_wanted_label_set():
    f = synth_frame("hdl64e", frames=1, seed=2, index=0, azimuth_bins=256)
    fi = frame_image(f.xyz, HDL64, labels=f.labels, label_set="semantickitti", ring=f.ring)
    with_instances = f.labels.astype(np.uint32) | (7 << 16)
    plane = pixel_classes(fi, with_instances, "semantickitti", "semantickitti")
    index = fi.image.index
    assert plane.dtype == np.int32 and plane.shape == index.shape
    assert np.all(plane[index < 0] == -1)
    owned = index >= 0
    assert np.array_equal(plane[owned], (f.labels & 0xFFFF)[index[owned]])
    assert np.all(pixel_classes(fi, f.labels, "semantickitti", "nuscenes") == -1)
    assert np.all(pixel_classes(fi, None, None, "semantickitti") == -1)


def test_class_offsets_separate_classes_of_one_material():
    frames = [_cached(s)[0] for s in (1, 2)]
    by_material = fit_law(frames, 0.005)
    by_class = fit_law(frames, 0.005, "semantickitti")
    assert by_material.class_label_set is None and not by_material.class_offsets
    assert by_class.class_label_set == "semantickitti"
    assert by_class.law == by_material.law  # offsets on top of the very same material law
    d = by_class.class_offsets
    assert d[PARKING] - d[ROAD] == pytest.approx(BRIGHTER_PARKING, abs=0.05)
    # Offsets apply to the classes of the law's label set only.
    material = np.zeros(4, dtype=np.int64)
    classes = np.array([PARKING, ROAD, -1, 7])  # 7: a class never seen
    assert by_class.offsets(classes, "semantickitti").tolist() == [d[PARKING], d[ROAD], 0, 0]
    assert by_class.offsets(classes, "nuscenes") == 0.0
    assert by_class.offsets(None, "semantickitti") == 0.0
    r, cos = np.full(4, 10.0), np.full(4, 0.7)
    base = by_class.law.ln_predict(material, r, cos)
    got = by_class.ln_predict(material, r, cos, classes=classes, label_set="semantickitti")
    assert np.allclose(got - base, [d[PARKING], d[ROAD], 0, 0])
    # JSON round trip; a law without offsets reads back as the material law.
    again = GroupedLaw.from_json(by_class.to_json())
    assert again.class_label_set == "semantickitti" and again.class_offsets == d
    assert again.law.intercepts == by_class.law.intercepts
    assert "class_offsets" not in by_material.to_json()
    plain = GroupedLaw.from_json(by_material.to_json())
    assert plain.class_label_set is None and not plain.class_offsets


def test_offsets_are_shrunk_medians_without_the_near_field_or_unlabelled_pixels():
    classes = np.array([5] * 100 + [6] * 100 + [-1] * 100 + [8] * 10)
    residual = np.concatenate([np.full(100, 1.0), np.full(100, 2.0), np.full(110, 3.0)])
    r = np.concatenate([np.full(100, 1.0), np.full(210, 10.0)])  # class 5: near field only
    d = class_offsets(classes, residual, r)
    assert set(d) == {6, 8}
    assert d[6] == pytest.approx(2.0 * 100 / (100 + CLASS_PRIOR_POINTS))
    assert d[8] == pytest.approx(3.0 * 10 / (10 + CLASS_PRIOR_POINTS))  # few: mostly 0


def test_the_torch_law_and_the_prediction_path_add_the_same_offsets():
    frames = [_cached(s)[0] for s in (1, 2)]
    law = fit_law(frames, 0.005, "semantickitti")
    held, labels = _cached(3, few_rider=False)
    names = channel_names(False)
    raw = torch.from_numpy(held.inputs)[None]
    classes = torch.from_numpy(held.classes)[None, None]
    torch_ln = TorchLaw.of(law, names).ln_reference(raw, torch.zeros(1), classes)[0, 0]
    f = synth_frame("hdl64e", frames=1, seed=3, index=0, azimuth_bins=512)
    fi = frame_image(f.xyz, HDL64, labels=labels, label_set="semantickitti", ring=f.ring)
    spec = TargetSpec("hdl64e", -1.5, 0.8, 0.005, 1.2, law=law.to_json())
    points = law_points(spec, fi, 0.0, labels, "semantickitti")
    index = fi.image.index
    owned = index >= 0
    assert np.allclose(torch_ln.numpy()[owned], points[index[owned]], atol=1e-4)
    parking, road = labels == PARKING, labels == ROAD
    other = law_points(spec, fi, 0.0, labels, "nuscenes")  # another label set: no offsets
    assert np.allclose(points[parking] - other[parking], law.class_offsets[PARKING])
    assert points[parking].mean() - points[road].mean() > 0.5
    assert abs(other[parking].mean() - other[road].mean()) < 0.2
    assert np.array_equal(law_points(spec, fi, 0.0), other)  # no labels: no offsets either
    with_instances = labels | (3 << 16)  # instance bits are not part of the class
    assert np.array_equal(law_points(spec, fi, 0.0, with_instances, "semantickitti"), points)


def test_law_groups_is_checked_in_the_config(tmp_path):
    text = (train_configs_dir() / "synth-to-kitti.yaml").read_text()
    path = tmp_path / "c.yaml"
    path.write_text(text + "law_groups: class\n")
    assert load_train_config(path, data_root=tmp_path).law_groups == "class"
    assert load_train_config("synth-to-kitti", data_root=tmp_path).law_groups in (
        "material",
        "class",
    )
    path.write_text(text + "law_groups: instance\n")
    with pytest.raises(ConfigError, match="law_groups = 'instance'"):
        load_train_config(path, data_root=tmp_path)
