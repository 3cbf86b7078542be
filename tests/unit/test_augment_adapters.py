"""The loader adapters of lads.augment: a PyTorch Dataset wrapper (real DataLoader, several
workers), the mmdetection3d transform built through mmengine's real registry, and the
OpenPCDet DataAugmentor entry against OpenPCDet's documented contract (pcdet needs compiled
CUDA ops and does not install here)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from lads.augment import Corruption
from lads.augment.torch_data import CorruptedDataset, worker_init_fn
from lads.physics.result import Outcome
from lads.sensors.profile import load_profile
from tests.conftest import street_frame


class Clouds(torch.utils.data.Dataset):
    """Three dict samples of tensors, as a user's dataset would return them."""

    def __init__(self) -> None:
        xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=240)
        self.points = torch.from_numpy(np.column_stack([xyz, intensity]).astype(np.float32))
        self.labels = torch.from_numpy(np.where(xyz[:, 2] < -1.5, 40, 50).astype(np.int64))

    def __len__(self) -> int:
        return 3

    def __getitem__(self, i: int) -> dict:
        shift = torch.tensor([float(i), 0.0, 0.0, 0.0])
        return {"points": self.points + shift, "labels": self.labels, "path": f"scan_{i}.bin"}


def _wrapped(**kw) -> CorruptedDataset:
    corruption = Corruption("snow", "heavy", sensor="hdl64e", particle_label=0, seed=7)
    return CorruptedDataset(Clouds(), corruption, labels_key="labels", id_key="path", **kw)


def _epoch(dataset: CorruptedDataset, workers: int) -> list[dict]:
    loader = DataLoader(
        dataset,
        batch_size=None,
        num_workers=workers,
        worker_init_fn=worker_init_fn if workers else None,
    )
    return list(loader)


def test_persistent_workers_draw_the_epoch_set_after_they_started():
    data = _wrapped()
    loader = DataLoader(
        data, batch_size=None, num_workers=2, persistent_workers=True, worker_init_fn=worker_init_fn
    )
    first = list(loader)
    data.set_epoch(1)
    second = list(loader)  # the same two worker processes
    fresh = _epoch(data, 0)  # epoch 1 drawn in this process
    assert data.epoch == 1
    for b, c in zip(second, fresh, strict=True):
        assert torch.equal(b["points"], c["points"]) and torch.equal(b["labels"], c["labels"])
    assert not torch.equal(first[0]["points"], second[0]["points"])
    copied = copy.deepcopy(data)  # a copied dataset keeps reading the same epoch
    data.set_epoch(2)
    assert copied.epoch == 2


def test_dataset_wrapper_same_bytes_with_any_worker_count_and_new_draw_per_epoch():
    data = _wrapped()
    one, two = _epoch(data, 0), _epoch(data, 2)
    for a, b in zip(one, two, strict=True):
        assert isinstance(a["points"], torch.Tensor) and a["points"].dtype == torch.float32
        assert torch.equal(a["points"], b["points"]) and torch.equal(a["labels"], b["labels"])
        assert a["labels"].shape[0] == a["points"].shape[0]
    data.set_epoch(1)
    assert not torch.equal(_epoch(data, 0)[0]["points"], one[0]["points"])


def test_dataset_wrapper_reports_info_and_honours_probability():
    data = _wrapped(info_key="lads")
    sample = data[0]
    assert sample["lads"].outcome.shape[0] == sample["points"].shape[0]
    untouched = _wrapped(probability=0.0)[1]
    assert torch.equal(untouched["points"], Clouds()[1]["points"])


class FakeLiDARPoints:
    """mmdet3d's BasePoints contract as LadsCorruption uses it: `.tensor` (N, C) and
    `new_point(tensor)` returning the same type."""

    def __init__(self, tensor: torch.Tensor) -> None:
        self.tensor = tensor

    def new_point(self, tensor: torch.Tensor) -> FakeLiDARPoints:
        return FakeLiDARPoints(tensor)


def test_mmdet3d_transform_builds_from_a_config_through_mmengine():
    pytest.importorskip("mmengine")
    from mmengine.dataset import Compose

    import lads.augment.mmdet3d  # noqa: F401  (registers the transform)

    pipeline = Compose(
        [
            dict(
                type="LadsCorruption",
                corruption="fog",
                severity="heavy",
                sensor="hdl64e",
                particle_label=19,
            )
        ]
    )
    xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=240)
    n = xyz.shape[0]
    points = torch.from_numpy(np.column_stack([xyz, intensity, np.ones(n)]).astype(np.float32))
    boxes = object()
    results = {
        "points": FakeLiDARPoints(points),
        "pts_semantic_mask": np.where(xyz[:, 2] < -1.5, 0, 1).astype(np.int64),
        "pts_instance_mask": np.arange(n, dtype=np.int64),
        "sample_idx": 42,
        "gt_bboxes_3d": boxes,
    }
    out = pipeline(results)
    new = out["points"].tensor
    assert isinstance(out["points"], FakeLiDARPoints) and new.shape[1] == 5
    assert new.shape[0] == out["pts_semantic_mask"].shape[0] == out["pts_instance_mask"].shape[0]
    fog = out["lads_outcome"] == Outcome.PARTICLE
    assert fog.any() and (out["pts_semantic_mask"][fog] == 19).all()
    assert out["gt_bboxes_3d"] is boxes


class PipelineDataset(torch.utils.data.Dataset):
    """mmengine's dataset contract as LadsEpochHook walks it: a `pipeline` (Compose) run on
    each sample's results dict."""

    def __init__(self, pipeline) -> None:
        xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=240)
        self.points = torch.from_numpy(np.column_stack([xyz, intensity]).astype(np.float32))
        self.pipeline = pipeline

    def __len__(self) -> int:
        return 2

    def __getitem__(self, i: int) -> torch.Tensor:
        results = self.pipeline({"points": FakeLiDARPoints(self.points.clone()), "sample_idx": i})
        return results["points"].tensor


class Repeated:
    """A dataset wrapper (mmengine's RepeatDataset holds the wrapped one as `.dataset`)."""

    def __init__(self, dataset) -> None:
        self.dataset = dataset


def test_mmdet3d_epoch_hook_reaches_the_transforms_in_persistent_workers():
    pytest.importorskip("mmengine")
    from mmengine.dataset import Compose
    from mmengine.registry import HOOKS

    import lads.augment.mmdet3d as adapter

    transform = dict(type="LadsCorruption", corruption="snow", severity="heavy", sensor="hdl64e",
                     particle_label=0)  # fmt: skip
    data = PipelineDataset(Compose([transform]))
    loader = DataLoader(data, batch_size=None, num_workers=2, persistent_workers=True)
    hook = HOOKS.build(dict(type="LadsEpochHook"))
    runner = type("Runner", (), {"epoch": 0, "train_dataloader": Repeated(loader)})()
    runner.train_dataloader.dataset = Repeated(data)  # the hook walks the wrappers
    hook.before_train_epoch(runner)
    first = list(loader)
    runner.epoch = 1
    hook.before_train_epoch(runner)
    second = list(loader)  # the same worker processes
    (lads,) = adapter.corruptions_in(runner.train_dataloader.dataset)
    assert lads.epoch == 1
    fresh = [data[i] for i in range(len(data))]  # epoch 1, in this process
    assert all(torch.equal(a, b) for a, b in zip(second, fresh, strict=True))
    assert not torch.equal(first[0], second[0])


class FakeDataAugmentor:
    """OpenPCDet's DataAugmentor contract: the queue is built with
    getattr(self, cfg.NAME)(config=cfg) and run as augmentor(data_dict=data_dict)."""

    def __init__(self, configs: list[dict]) -> None:
        self.queue = [getattr(self, cfg["NAME"])(config=cfg) for cfg in configs]

    def forward(self, data_dict: dict) -> dict:
        for augmentor in self.queue:
            data_dict = augmentor(data_dict=data_dict)
        return data_dict


def test_openpcdet_entry_corrupts_points_and_keeps_boxes():
    from lads.augment.openpcdet import install

    install(FakeDataAugmentor)
    config = {"NAME": "lads_corruption", "CORRUPTION": "beam_missing", "SEVERITY": "moderate",
              "SENSOR": "hdl64e", "SEED": 1}  # fmt: skip
    augmentor = FakeDataAugmentor([config])
    xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=240)
    points = np.column_stack([xyz, intensity]).astype(np.float32)
    boxes = np.ones((2, 7), np.float32)
    out = augmentor.forward({"points": points, "gt_boxes": boxes, "frame_id": "000123"})
    assert out["points"].shape[1] == 4 and 0 < out["points"].shape[0] < points.shape[0] * 0.7
    assert out["gt_boxes"] is boxes
    again = FakeDataAugmentor([config]).forward({"points": points, "frame_id": "000123"})
    np.testing.assert_array_equal(again["points"], out["points"])


def _box_around(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 5 x 3 x 4 m box (heading 30 deg) centred on the street point nearest (15, 0, 0),
    and which points it holds."""
    from lads.augment.pseudo_labels import points_in_boxes

    centre = points[np.argmin(np.linalg.norm(points[:, :3] - (15.0, 0.0, 0.0), axis=1)), :3]
    box = np.array([[*centre, 5.0, 3.0, 4.0, np.radians(30.0)]])
    return box, points_in_boxes(points[:, :3], box)


def test_points_in_a_turned_box():
    from lads.augment.pseudo_labels import points_in_boxes

    box = np.array([[10.0, 0.0, 0.0, 4.0, 2.0, 2.0, np.pi / 2]])  # long side along y
    pts = np.array([[10.0, 1.9, 0.0], [11.9, 0.0, 0.0], [10.0, 0.0, 1.1], [10.5, -1.5, 0.5]])
    np.testing.assert_array_equal(points_in_boxes(pts, box), [True, False, False, True])


def test_openpcdet_incomplete_echo_finds_vehicles_by_their_boxes():
    from lads.augment.openpcdet import OpenPCDetCorruption

    xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=720)
    points = np.column_stack([xyz, intensity]).astype(np.float32)
    box, inside = _box_around(points)
    assert inside.sum() > 20
    config = {"NAME": "lads_corruption", "CORRUPTION": "incomplete_echo", "SEVERITY": "heavy",
              "SENSOR": "hdl64e"}  # fmt: skip
    entry = OpenPCDetCorruption(config)
    car = entry({"points": points, "gt_boxes": box, "gt_names": np.array(["Car"]), "frame_id": "1"})
    sign = entry(
        {"points": points, "gt_boxes": box, "gt_names": np.array(["Pedestrian"]), "frame_id": "1"}
    )
    assert car["points"].shape[0] < points.shape[0]
    rows = {tuple(r) for r in car["points"].tolist()}
    assert all(tuple(r) in rows for r in points[~inside].tolist())  # the rest is untouched
    np.testing.assert_array_equal(sign["points"], points)  # not a vehicle: untouched
    wet = OpenPCDetCorruption({**config, "CORRUPTION": "wet_ground"})(
        {"points": points, "frame_id": "1"}
    )
    assert wet["points"].shape[0] < points.shape[0]  # the fitted road loses grazing returns


class FakeBoxes:
    """mmdet3d's BaseInstance3DBoxes as LadsCorruption reads it."""

    def __init__(self, box: np.ndarray) -> None:
        self.gravity_center = torch.from_numpy(box[:, :3])
        self.dims = torch.from_numpy(box[:, 3:6])
        self.yaw = torch.from_numpy(box[:, 6])


def test_mmdet3d_incomplete_echo_from_boxes_without_point_masks():
    from lads.augment.mmdet3d import LadsCorruption

    xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=720)
    points = np.column_stack([xyz, intensity]).astype(np.float32)
    box, inside = _box_around(points)
    t = LadsCorruption("incomplete_echo", severity="heavy", sensor="hdl64e", vehicle_classes=[0])
    results = {
        "points": torch.from_numpy(points),
        "gt_bboxes_3d": FakeBoxes(box),
        "gt_labels_3d": np.array([0]),
        "sample_idx": 3,
    }
    out = t.transform(results)
    assert out["points"].shape[0] < points.shape[0] and "pts_semantic_mask" not in out
    changed = out["lads_outcome"] != Outcome.KEPT
    assert changed.sum() + (points.shape[0] - out["points"].shape[0]) <= inside.sum()


def test_dataset_wrapper_keeps_tuple_and_named_tuple_samples():
    from collections import namedtuple

    Sample = namedtuple("Sample", "points labels")
    base = Clouds()
    plain = [(base[0]["points"], base[0]["labels"])]
    named = [Sample(base[0]["points"], base[0]["labels"])]
    corruption = Corruption("beam_missing", "light", sensor="hdl64e", seed=2)
    for samples in (plain, named):
        out = CorruptedDataset(samples, corruption, points_key=0, labels_key=1)[0]
        assert type(out) is type(samples[0]) and out[0].shape[0] == out[1].shape[0]
        assert out[0].shape[0] < samples[0][0].shape[0]


class AugmentedFrames(torch.utils.data.Dataset):
    """An OpenPCDet-like dataset: its DataAugmentor runs in the DataLoader's workers."""

    def __init__(self) -> None:
        from lads.augment.openpcdet import install

        install(FakeDataAugmentor)
        config = {"NAME": "lads_corruption", "CORRUPTION": "rain", "SEVERITY": "heavy",
                  "SENSOR": "hdl64e"}  # fmt: skip
        self.augmentor = FakeDataAugmentor([config])
        xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=240)
        self.points = np.column_stack([xyz, intensity]).astype(np.float32)

    def __len__(self) -> int:
        return 2

    def __getitem__(self, i: int) -> np.ndarray:
        return self.augmentor.forward({"points": self.points.copy(), "frame_id": str(i)})["points"]


def test_openpcdet_set_epoch_reaches_persistent_workers():
    from lads.augment.openpcdet import set_epoch

    data = AugmentedFrames()
    loader = DataLoader(data, batch_size=None, num_workers=2, persistent_workers=True)
    set_epoch(0)
    first = list(loader)
    set_epoch(1)
    second = list(loader)
    fresh = [data[i] for i in range(len(data))]
    set_epoch(0)  # the module's epoch is shared by every entry of this process
    assert all(
        torch.equal(torch.as_tensor(a), torch.as_tensor(b))
        for a, b in zip(second, fresh, strict=True)
    )
    assert not torch.equal(torch.as_tensor(first[0]), torch.as_tensor(second[0]))


def test_adapters_refuse_mistaken_settings_by_name():
    from lads.augment.mmdet3d import LadsCorruption
    from lads.augment.openpcdet import OpenPCDetCorruption
    from lads.augment.shared_epoch import SharedEpoch
    from lads.errors import AugmentInputError

    positional = LadsCorruption("snow", "heavy", sensor="hdl64e", particle_label=0)
    assert positional.corruption.severity == "heavy"  # as Corruption("snow", "heavy", ...)
    entry = {"NAME": "lads_corruption", "CORRUPTION": "fog", "SENSOR": "hdl64e"}
    for probability in (2.0, -1.0, "half"):
        with pytest.raises(AugmentInputError, match="probability"):
            OpenPCDetCorruption({**entry, "SEVERITY": "light", "PROBABILITY": probability})
    with pytest.raises(AugmentInputError, match="no SENSOR key"):
        OpenPCDetCorruption({"NAME": "lads_corruption", "CORRUPTION": "fog", "SEVERITY": "light"})
    for epoch in (-1, 1.5):
        with pytest.raises(AugmentInputError, match="whole number"):
            SharedEpoch().set(epoch)
    with pytest.raises(AugmentInputError, match="no 'mask', the labels_key"):
        CorruptedDataset(Clouds(), Corruption("fog", "light", sensor="hdl64e"), labels_key="mask")[
            0
        ]


def test_boxes_without_a_name_each_are_refused_for_incomplete_echo():
    from lads.augment.openpcdet import OpenPCDetCorruption
    from lads.errors import AugmentInputError

    xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=240)
    points = np.column_stack([xyz, intensity]).astype(np.float32)
    entry = OpenPCDetCorruption({"NAME": "lads_corruption", "CORRUPTION": "incomplete_echo",
                                 "SEVERITY": "heavy", "SENSOR": "hdl64e"})  # fmt: skip
    sample = {"points": points, "gt_boxes": np.ones((2, 7), np.float32), "frame_id": "1"}
    for names in ([], ["Car"]):  # none, or fewer than the boxes: their classes are unknown
        with pytest.raises(AugmentInputError, match="2 gt_boxes but"):
            entry({**sample, "gt_names": names} if names else sample)
    entry({**sample, "gt_names": ["Car", "Pedestrian"]})


def test_ring_values_and_encodings_that_do_not_fit_the_sensor_are_refused():
    from lads.errors import AugmentInputError, IntensityEncodingError

    xyz, intensity = street_frame(load_profile("hdl32e"), azimuths=240)
    ring = np.zeros(len(xyz), np.float32)
    points = np.column_stack([xyz, intensity, ring]).astype(np.float32)
    points[3, 4] = 40.0  # an HDL-32E has lasers 0..31
    for name in ("fog", "beam_missing"):
        with pytest.raises(AugmentInputError, match="ring values"):
            Corruption(name, "light", sensor="hdl32e", ring_column=4)(points, sample_id="x")
    unit = points[:, :4].copy()
    unit[:, 3] = np.linspace(0.0, 0.99, len(unit))  # SemanticKITTI remission
    with pytest.raises(IntensityEncodingError, match="look unit-encoded"):
        Corruption("fog", "light", sensor="hdl32e")(unit, sample_id="x")
