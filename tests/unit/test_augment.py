"""lads.augment's transform API: layout and dtype kept, labels re-indexed, provenance, seeding
from the sample's identity, and named errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest

from lads.augment import CORRUPTIONS, SEVERITIES, Corruption, augment_rng, corrupt
from lads.errors import AugmentInputError, ConfigError, IntensityEncodingError
from lads.physics.result import Outcome
from lads.sensors.profile import load_profile
from tests.conftest import street_frame

# The corruptions with severity presets (cross-sensor names a target sensor instead).
GRADED = [name for name, spec in CORRUPTIONS.items() if spec.has_presets]


@pytest.fixture(scope="module")
def cloud() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A synthetic HDL-64E sweep with a 5th column (a per-point time stamp), classes and
    instance ids that are functions of the row, so re-indexing can be checked exactly."""
    xyz, intensity = street_frame(load_profile("hdl64e"), azimuths=360)
    n = xyz.shape[0]
    time_s = np.linspace(0.0, 0.1, n, dtype=np.float32)
    points = np.column_stack([xyz, intensity, time_s]).astype(np.float32)
    labels = np.where(xyz[:, 2] < -1.5, 40, 50).astype(np.uint32)  # road below, building above
    instance = (np.arange(n) % 7).astype(np.int32)
    return points, labels, instance


@pytest.mark.parametrize("name", GRADED)
def test_every_corruption_keeps_columns_and_reindexes_labels(cloud, name):
    points, labels, instance = cloud
    c = Corruption(name, "heavy", sensor="hdl64e", dataset="semantickitti")
    out = c(points, labels, instance, sample_id="frame-1")
    info = out.info
    m = out.points.shape[0]
    assert out.points.dtype == points.dtype and out.points.shape[1] == points.shape[1]
    assert info.source_index.shape == info.outcome.shape == (m,)
    assert out.labels.shape == out.instance.shape == (m,)
    # Every input row is either the source of an output point or lost, never both.
    assert set(info.source_index.tolist()).isdisjoint(info.lost_index.tolist())
    assert len(set(info.source_index.tolist())) + info.lost_index.size == points.shape[0]
    # The extra column follows the source beam; non-particle labels and instances too.
    np.testing.assert_array_equal(out.points[:, 4], points[info.source_index, 4])
    beam = info.outcome != Outcome.PARTICLE
    np.testing.assert_array_equal(out.labels[beam], labels[info.source_index[beam]])
    np.testing.assert_array_equal(out.instance[beam], instance[info.source_index[beam]])
    assert (out.labels[~beam] == 1).all() and (out.instance[~beam] == 0).all()  # KITTI outlier


def test_float64_input_stays_float64_and_exact_where_untouched(cloud):
    points, labels, _ = cloud
    p64 = points.astype(np.float64) + 1e-9  # values float32 cannot hold
    out = corrupt(
        p64,
        rng=augment_rng(0, "a", 0, "beam_missing"),
        corruption="beam_missing",
        severity="moderate",
        sensor="hdl64e",
    )
    assert out.points.dtype == np.float64
    np.testing.assert_array_equal(out.points, p64[out.info.source_index])


def test_same_sample_same_epoch_same_bytes_other_epoch_differs(cloud):
    points, labels, instance = cloud
    c = Corruption("snow", "heavy", sensor="hdl64e", particle_label=255, seed=3)
    a = c(points, labels, instance, sample_id="s", epoch=1)
    b = Corruption("snow", "heavy", sensor="hdl64e", particle_label=255, seed=3)(
        points, labels, instance, sample_id="s", epoch=1
    )
    other = c(points, labels, instance, sample_id="s", epoch=2)
    assert a.points.tobytes() == b.points.tobytes()
    assert a.labels.tobytes() == b.labels.tobytes()
    assert a.points.tobytes() != other.points.tobytes()
    assert (a.labels[a.info.outcome == Outcome.PARTICLE] == 255).all()


def test_severity_sets_the_documented_physical_value():
    c = Corruption("fog", "moderate", sensor="hdl64e")
    assert c.params["visibility_m"] == CORRUPTIONS["fog"].preset("moderate") == 150.0
    assert Corruption("rain", sensor="hdl64e", rate_mm_h=8.0).params == {"rate_mm_h": 8.0}
    assert Corruption("motion_blur", "light", sensor="hdl64e").spec.name == "motion_distortion"


def test_dual_mode_second_returns_repeat_their_source_row(cloud):
    points, labels, _ = cloud
    c = Corruption("fog", "heavy", sensor="hdl64e", particle_label=0, mode="dual")
    out = c(points, labels, sample_id="d")
    repeats = np.diff(out.info.source_index) == 0
    assert repeats.any()
    assert (np.diff(out.info.source_index) >= 0).all()


def test_zero_range_rows_pass_through_every_corruption(cloud):
    points, labels, instance = cloud
    with_zero = np.vstack([points, np.zeros((5, points.shape[1]), np.float32)])
    lab = np.concatenate([labels, np.zeros(5, labels.dtype)])
    ins = np.concatenate([instance, np.zeros(5, instance.dtype)])
    for name in GRADED:
        out = Corruption(name, "heavy", sensor="hdl64e", dataset="semantickitti")(
            with_zero, lab, ins, sample_id="z"
        )
        assert np.isfinite(out.points).all(), name
    # every laser dead: the rows at zero range are no laser's returns, and stay
    dead = Corruption("beam_missing", sensor="hdl64e", lost_channel_share=1.0)
    out = dead(with_zero, lab, ins, sample_id="z")
    n = points.shape[0]
    assert out.info.source_index.tolist() == list(range(n, n + 5))
    assert (out.info.outcome == Outcome.KEPT).all() and not out.points.any()


def test_fixed_dead_lasers_need_no_share(cloud):
    from lads.physics.projection import channels_of

    points, labels, instance = cloud
    dead = Corruption("beam_missing", sensor="hdl64e", channels=[5, 17])
    out = dead(points, labels, instance, sample_id="x")
    laser = channels_of(points[:, :3].astype(np.float64), load_profile("hdl64e"), None)
    assert sorted(out.info.lost_index) == sorted(np.flatnonzero(np.isin(laser, [5, 17])))
    assert out.info.conditions["dead_channels"] == "5 17"


@pytest.mark.parametrize("bad", [np.nan, np.inf, 2e4])
@pytest.mark.parametrize("name", GRADED)
def test_unusable_coordinates_are_refused_by_every_corruption(cloud, name, bad):
    points, labels, instance = cloud
    broken = points.copy()
    broken[3, 0] = bad  # a far stray point once made the particle table grow without bound
    c = Corruption(name, "light", sensor="hdl64e", dataset="semantickitti")
    with pytest.raises(AugmentInputError, match="point 3, column 'x'"):
        c(broken, labels, instance, sample_id="bad")


@pytest.mark.parametrize(("dtype", "label"), [(np.uint32, -1), (np.uint8, 300), (np.int8, 200)])
def test_a_particle_label_the_labels_cannot_hold_is_refused(cloud, dtype, label):
    points, labels, _ = cloud
    c = Corruption("snow", "light", sensor="hdl64e", particle_label=label)
    with pytest.raises(AugmentInputError, match=f"particle_label {label}"):
        c(points, labels.astype(dtype), sample_id="x")
    out = c(points, labels.astype(np.int64), sample_id="x")  # a wide signed dtype holds it
    assert (out.labels[out.info.outcome == Outcome.PARTICLE] == label).all()


@pytest.mark.parametrize(
    ("points", "labels", "message"),
    [
        (np.zeros((10, 3), np.float32), None, "C >= 4"),
        (np.zeros((10, 4), np.int32), None, "float32 or float64"),
        (np.zeros((10, 4), np.float32), np.zeros(9, np.uint32), r"shape \(9,\)"),
    ],
)
def test_bad_arrays_raise_named_errors(points, labels, message):
    c = Corruption("rain", "light", sensor="hdl64e", particle_label=0)
    with pytest.raises(AugmentInputError, match=message):
        c(points, labels, sample_id="bad")


def test_bad_configuration_and_encoding_raise_named_errors(cloud):
    points, labels, _ = cloud
    with pytest.raises(ConfigError, match="severity 'extreme'"):
        Corruption("fog", "extreme", sensor="hdl64e")
    with pytest.raises(ConfigError, match="unknown corruption"):
        Corruption("hail", "light", sensor="hdl64e")
    with pytest.raises(ConfigError, match="unknown parameters"):
        Corruption("fog", "light", sensor="hdl64e", rate_mm_h=3.0)
    with pytest.raises(AugmentInputError, match="particle_label"):
        Corruption("snow", "light", sensor="hdl64e")(points, labels, sample_id="x")
    with pytest.raises(AugmentInputError, match="reads point classes"):
        Corruption("wet_ground", "light", sensor="hdl64e")(points, labels, sample_id="x")
    scaled = points.copy()
    scaled[:, 3] *= 255.0
    with pytest.raises(IntensityEncodingError, match="hdl32e"):
        Corruption("rain", "light", sensor="hdl64e")(scaled, sample_id="x")
    with pytest.raises(AugmentInputError, match="rng"):
        corrupt(points, corruption="rain", severity="light", sensor="hdl64e")


def test_every_graded_corruption_has_all_severities():
    for spec in (CORRUPTIONS[name] for name in GRADED):
        values = [spec.preset(s) for s in SEVERITIES]
        assert values == sorted(values) or values == sorted(values, reverse=True), spec.name


def test_cross_sensor_rescans_with_the_target_and_keeps_the_layout(cloud):
    points, labels, instance = cloud
    c = Corruption("cross_sensor", sensor="hdl64e", dataset="semantickitti", target="hdl32e")
    out = c(points, labels, instance, sample_id="t")
    info = out.info
    assert info.sensor == "hdl32e" and (info.outcome == Outcome.RESAMPLED).all()
    assert out.points.shape[1] == points.shape[1] and out.points.dtype == points.dtype
    # x, y, z, intensity are the target's beams (its 0-255 encoding); the time column and the
    # labels are those of the source return each beam hit.
    assert out.points[:, 3].max() > 1.0
    np.testing.assert_array_equal(out.points[:, 4], points[info.source_index, 4])
    np.testing.assert_array_equal(out.labels, labels[info.source_index])
    channel = load_profile("hdl32e").channel_of(out.points[:, :3])
    assert np.unique(channel).size > 16  # many of the target's rings, not the source's 64
    with pytest.raises(ConfigError, match="no severities"):
        Corruption("cross_sensor", "heavy", sensor="hdl64e", target="hdl32e")


def test_wet_ground_without_labels_lies_on_the_fitted_ground(cloud):
    points, labels, _ = cloud
    out = Corruption("wet_ground", "heavy", sensor="hdl64e")(points, sample_id="g")
    assert out.labels is None and out.info.conditions["ground"] == "fitted"
    changed = np.zeros(points.shape[0], bool)
    changed[out.info.lost_index] = True
    changed[out.info.source_index[out.info.outcome != Outcome.KEPT]] = True
    assert changed.sum() > 0.2 * (labels == 40).sum()
    # What the wet road changed is ground: the street's road class, not the buildings.
    assert (labels[changed] == 40).mean() > 0.9


def test_motion_distortion_at_a_motion_made_from_the_users_poses(cloud):
    from lads.augment import ego_motion_from_poses

    points, labels, instance = cloud
    poses = np.stack([np.eye(4)] * 3)
    poses[:, 0, 3] = [-1.2, 0.0, 1.2]  # 12 m/s along x at 10 Hz
    motion = ego_motion_from_poses([0.0, 0.1, 0.2], poses, 1, "my poses")

    def distort(**params):
        rng = np.random.default_rng(0)
        kind = {"corruption": "motion_distortion", "sensor": "hdl64e"}
        return corrupt(points, labels, instance, rng, **kind, **params)

    given, preset = distort(**motion.params()), distort(speed_m_s=12.0)
    np.testing.assert_allclose(given.points, preset.points, atol=1e-5)
    assert given.info.conditions["speed_m_s"] == pytest.approx(12.0)
    with pytest.raises(ConfigError, match="ego_motion_from_poses"):
        distort(ego_motion="poses")
    with pytest.raises(ConfigError, match="give one"):
        Corruption("motion_distortion", "light", sensor="hdl64e", velocity_m_s=[1.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match="three finite numbers"):
        Corruption("motion_distortion", sensor="hdl64e", velocity_m_s=[1.0, 0.0])
