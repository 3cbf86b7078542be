"""Intensity evaluation: lads/intensity/evaluate.py (metrics, baselines, report) and
lads/intensity/eval_figures.py (PNG figures).

The frames are synthetic streets scanned with the HDL-64E geometry and SemanticKITTI labels:
road and sidewalk on the ground, building facades 10 m to each side, a traffic sign on one
facade. Their "real" intensity follows a known law, K I_P with log-normal noise, so the
right answer of every metric is known in advance.
"""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

from lads.errors import ConfigError, InputDataError, InvalidPointsError
from lads.intensity import eval_figures
from lads.intensity.baselines import BASELINES, MIN_CLASS_REFERENCE_POINTS, fit_baselines
from lads.intensity.eval_report import write_report
from lads.intensity.evaluate import (
    EvalFrame,
    class_ids,
    evaluate,
    physics_image,
    retro_classes,
)
from lads.physics.materials import LABEL_SETS, reflectance_for_labels
from lads.sensors.profile import SensorProfile, load_profile

HDL64 = load_profile("hdl64e")
FINE = load_profile("voxelscape64")  # 1e-4 steps: quantisation does not blur k
ROAD, SIDEWALK, BUILDING, VEGETATION, TERRAIN, SIGN = 40, 48, 50, 70, 72, 81
K_TRUE = 12.0  # real reflectivity = K_TRUE * I_P (I_P ~ 1e-3..0.07 m^-1 here)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def street(seed: int, *, azimuths: int = 256, sign: bool = True):
    """xyz (N, 3) m, ring (N,) and SemanticKITTI labels (N,) with instance bits; N ~ 16k."""
    rng = np.random.default_rng(seed)
    el = np.radians(np.asarray(HDL64.elevation_deg))[:, None]
    az = (np.arange(azimuths) + rng.random()) * 2 * np.pi / azimuths - np.pi
    el, az = np.broadcast_arrays(el, az[None, :])
    ring = np.broadcast_to(np.arange(HDL64.channels)[:, None], el.shape).reshape(-1)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    d = d.reshape(-1, 3)
    with np.errstate(divide="ignore"):
        t_ground = np.where(d[:, 2] < 0, -1.73 / d[:, 2], np.inf)
        t_facade = np.where(d[:, 1] != 0, 10.0 / np.abs(d[:, 1]), np.inf)
    t = np.minimum(t_ground, t_facade)
    xyz = d * t[:, None]
    facade = t_facade < t_ground
    keep = np.isfinite(t) & (t < 60.0) & (xyz[:, 2] < 6.0)
    xyz, ring, facade = xyz[keep], ring[keep], facade[keep]
    on_road = np.abs(xyz[:, 1]) < 5.0
    labels = np.where(facade, BUILDING, np.where(on_road, ROAD, SIDEWALK)).astype(np.uint32)
    if sign:
        x, z = xyz[:, 0], xyz[:, 2]
        labels[facade & (x > 4) & (x < 8) & (z > 0) & (z < 2)] = SIGN
    labels |= rng.integers(0, 5, len(labels)).astype(np.uint32) << 16  # instance ids
    return xyz.astype(np.float32), ring, labels


def make_frame(
    name: str,
    seed: int,
    *,
    profile: SensorProfile = HDL64,
    noise: float = 0.15,
    sign: bool = True,
    relabel: tuple[int, int] | None = None,
    labelled: bool = True,
    extinction_per_m: float = 0.0,
) -> EvalFrame:
    """A street frame whose real reflectivity is K_TRUE * I_P * exp(noise * N(0, 1)).

    relabel=(class, count) gives `count` facade points (the farthest first) class `class`.
    """
    xyz, ring, labels = street(seed, sign=sign)
    if relabel is not None:
        cls, count = relabel
        facade = np.flatnonzero((labels & 0xFFFF) == BUILDING)
        far = facade[np.argsort(-np.abs(xyz[facade, 0]), kind="stable")][:count]
        labels[far] = cls
    label_set = "semantickitti" if labelled else None
    bare = EvalFrame(
        name,
        xyz,
        np.zeros(len(xyz), np.float32),
        profile,
        labels if labelled else None,
        label_set,
        ring,
        extinction_per_m=extinction_per_m,
    )
    physics = physics_image(bare).physics.astype(np.float64)
    rng = np.random.default_rng(seed + 1000)
    refl = K_TRUE * physics * np.exp(noise * rng.standard_normal(len(xyz)))
    return EvalFrame(
        name,
        xyz,
        profile.intensity.from_reflectivity(refl),
        profile,
        bare.labels,
        label_set,
        ring,
        extinction_per_m=extinction_per_m,
    )


def perfect(frame: EvalFrame) -> np.ndarray:
    return frame.intensity


def shifted(offset: float):
    """A method that is the real intensity plus `offset` (clipped to the encoding)."""

    def method(frame: EvalFrame) -> np.ndarray:
        refl = frame.profile.intensity.to_reflectivity(frame.intensity) + offset
        return frame.profile.intensity.from_reflectivity(refl)

    return method


@pytest.fixture(scope="module")
def reference() -> list[EvalFrame]:
    return [make_frame(f"ref-{i}", i) for i in range(2)]


@pytest.fixture(scope="module")
def heldout() -> list[EvalFrame]:
    return [make_frame("held-0", 10), make_frame("held-1", 11)]


@pytest.fixture(scope="module")
def baselines(reference):
    return fit_baselines(reference)


@pytest.fixture(scope="module")
def result(heldout, baselines):
    """Baselines, an oracle, and a 'generator' that beats some methods and loses to others."""
    methods = dict(baselines)
    methods["oracle"] = perfect
    methods["generator"] = shifted(0.02)
    methods["worse"] = shifted(0.05)
    return evaluate(heldout, methods)


# --- paired and distributional metrics ---------------------------------------------------


def test_a_perfect_method_has_zero_error_unit_correlation_and_zero_distance(heldout):
    res = evaluate(heldout, {"perfect": perfect})
    frames = [res.per_frame[name]["perfect"] for name in res.frame_names]
    for metrics in [res.pooled["perfect"], *frames]:
        assert metrics["mae_encoded"] == 0.0
        assert metrics["mae_reflectivity"] == 0.0
        assert metrics["pearson_r"] == pytest.approx(1.0)
        assert metrics["spearman_rho"] == pytest.approx(1.0)
        assert metrics["global_w1_reflectivity"] == 0.0
        assert metrics["global_ks"] == 0.0
        assert metrics["cell_w1_reflectivity"] == 0.0
        assert metrics["cell_ks"] == 0.0
        assert metrics["retro_contrast_ratio"] == pytest.approx(1.0)
        assert all(v == pytest.approx(1.0) for v in metrics["class_ratio"].values())


def test_metrics_are_computed_on_all_points_and_pooled_over_frames(result, heldout):
    total = sum(f.n_points for f in heldout)
    assert result.pooled["oracle"]["points"] == total
    assert [result.per_frame[f.name]["oracle"]["points"] for f in heldout] == [
        f.n_points for f in heldout
    ]
    # A constant offset is a paired error of exactly that offset (minus clipped points).
    assert result.pooled["generator"]["mae_reflectivity"] == pytest.approx(0.02, abs=1e-3)


def test_cells_split_class_range_and_incidence_and_need_30_points(result):
    pooled = result.pooled["oracle"]
    # 4 classes x 5 range bins x 4 incidence bins at most; small cells are left out.
    assert 4 <= pooled["cells"] <= 4 * 5 * 4
    assert 0.9 < pooled["cell_coverage"] <= 1.0


def test_class_ratio_is_mean_prediction_over_mean_real_for_classes_with_50_points(heldout):
    def doubled(frame):
        return frame.intensity * 2.0

    res = evaluate(heldout, {"doubled": doubled})
    ratios = res.pooled["doubled"]["class_ratio"]
    assert set(ratios) == {"road", "sidewalk", "building", "traffic-sign"}
    assert all(v == pytest.approx(2.0) for v in ratios.values())
    assert res.pooled["doubled"]["class_ratio_count"] == 4
    assert res.pooled["doubled"]["class_ratio_mean_abs_log"] == pytest.approx(np.log(2.0))


def test_zero_shares_count_exact_zeros_per_class_of_the_prediction_and_the_real(heldout):
    def road_zeroed(frame):
        out = frame.intensity.astype(np.float64).copy()
        out[(frame.labels & 0xFFFF) == 40] = 0.0  # every road point
        return out

    # Real returns of exactly 0 on every third point, as KITTI reports for many.
    frames = []
    for f in heldout:
        real = f.intensity.copy()
        real[::3] = 0.0
        frames.append(dataclasses.replace(f, intensity=real))
    res = evaluate(frames, {"road_zeroed": road_zeroed})
    pooled = res.pooled["road_zeroed"]
    real = np.concatenate([f.intensity for f in frames])
    labels = np.concatenate([f.labels & 0xFFFF for f in frames])
    assert set(pooled["class_zero_share_pred"]) == set(pooled["class_ratio"])
    assert pooled["class_zero_share_pred"]["road"] == 1.0
    sidewalk = labels == 48
    assert pooled["class_zero_share_pred"]["sidewalk"] == pytest.approx(
        float(np.mean(real[sidewalk] == 0))
    )
    for name, code in (("road", 40), ("sidewalk", 48)):
        share = float(np.mean(real[labels == code] == 0))
        assert 0.3 < share < 0.4
        assert pooled["class_zero_share_real"][name] == pytest.approx(share)


def test_an_unlabelled_frame_is_one_class_called_all():
    frame = make_frame("unlabelled", 20, labelled=False)
    res = evaluate([frame], {"perfect": perfect})
    assert res.class_names == ("all",)
    assert list(res.pooled["perfect"]["class_ratio"]) == ["all"]
    assert np.isnan(res.pooled["perfect"]["retro_contrast_real"])  # no classes, no signs


# --- baselines ---------------------------------------------------------------------------


def test_fit_baselines_returns_the_four_baselines(baselines):
    assert tuple(baselines) == BASELINES


def test_unchanged_is_what_a_simulator_stores_rho_cos_theta_attenuated():
    clear = make_frame("clear", 30)
    foggy = make_frame("foggy", 30, extinction_per_m=0.02)
    methods = fit_baselines([clear])
    for frame, alpha in ((clear, 0.0), (foggy, 0.02)):
        fi = physics_image(frame)
        expected = fi.reflectance * fi.cos_incidence * np.exp(-2 * alpha * fi.range_m)
        np.testing.assert_array_equal(
            methods["unchanged"](frame), HDL64.intensity.from_reflectivity(expected)
        )


def test_physics_rescaled_recovers_k_from_data_made_as_k_times_physics():
    frames = [make_frame(f"fine-{i}", i, profile=FINE, noise=0.0) for i in range(2)]
    fitted = fit_baselines(frames)["physics_rescaled"]
    assert fitted.k == pytest.approx(K_TRUE, rel=0.005)
    prediction = fitted(frames[0])
    fi = physics_image(frames[0])
    np.testing.assert_allclose(
        FINE.intensity.to_reflectivity(prediction),
        np.minimum(K_TRUE * fi.physics, FINE.intensity.max_value),
        rtol=0.01,
        atol=1e-4,
    )


def test_physics_rescaled_uses_the_range_exponent():
    frames = [make_frame("fine", 3, profile=FINE, noise=0.0)]
    n1 = fit_baselines(frames)["physics_rescaled"].k
    n2 = fit_baselines(frames, range_exponent=2.0)["physics_rescaled"].k
    # I_P with n = 2 is I_P(n = 1) / R, so k grows by about the median range (~10 m).
    assert 3 < n2 / n1 < 30


def test_global_histogram_matching_reproduces_the_reference_marginal(result, baselines, heldout):
    hist = result.pooled["histogram_global"]["global_w1_reflectivity"]
    unchanged = result.pooled["unchanged"]["global_w1_reflectivity"]
    assert hist < 0.003
    assert hist < unchanged / 5


def test_histogram_matching_keeps_the_order_of_the_physics_intensity(baselines, heldout):
    frame = heldout[0]
    order = np.argsort(physics_image(frame).physics, kind="stable")
    predicted = baselines["histogram_global"](frame)[order]
    assert np.all(np.diff(predicted) >= 0)


def test_per_class_matching_fits_classes_with_20_reference_points(reference):
    few = make_frame("few", 1, relabel=(TERRAIN, MIN_CLASS_REFERENCE_POINTS - 1))
    enough = make_frame("enough", 2, relabel=(VEGETATION, MIN_CLASS_REFERENCE_POINTS))
    tables = fit_baselines([few, enough])["histogram_per_class"].class_tables
    assert ("semantickitti", VEGETATION) in tables
    assert ("semantickitti", TERRAIN) not in tables
    assert ("semantickitti", ROAD) in tables


def test_per_class_matching_falls_back_to_global_for_unseen_classes(baselines):
    frame = make_frame("with-vegetation", 12, relabel=(VEGETATION, 500))
    per_class = baselines["histogram_per_class"](frame)
    global_ = baselines["histogram_global"](frame)
    unseen = class_ids(frame.labels, "semantickitti") == VEGETATION
    np.testing.assert_array_equal(per_class[unseen], global_[unseen])
    assert not np.array_equal(per_class[~unseen], global_[~unseen])


def test_per_class_matching_is_global_matching_on_unlabelled_frames(baselines):
    frame = make_frame("unlabelled", 13, labelled=False)
    np.testing.assert_array_equal(
        baselines["histogram_per_class"](frame), baselines["histogram_global"](frame)
    )


def test_an_empty_reference_cannot_fit_baselines():
    with pytest.raises(InputDataError, match="no reference frames"):
        fit_baselines([])
    empty = EvalFrame("empty", np.zeros((0, 3), np.float32), np.zeros(0, np.float32), HDL64)
    with pytest.raises(InputDataError, match="no reference frames with points"):
        fit_baselines([empty])


# --- retro-reflector contrast ------------------------------------------------------------


def test_retro_reflective_classes_come_from_the_materials_table():
    assert retro_classes("semantickitti") == {SIGN}
    assert retro_classes("wads") == {SIGN}
    assert 256 in retro_classes("voxelscape")  # construction-cone
    assert 12 in retro_classes("nuscenes")  # trafficcone: retroreflective collars


def test_traffic_signs_give_a_high_real_contrast_that_a_flat_method_misses(result):
    pooled = result.pooled
    assert pooled["oracle"]["retro_contrast_real"] > 3.0
    assert pooled["oracle"]["retro_contrast_ratio"] == pytest.approx(1.0)

    def flat(frame):
        return np.full(frame.n_points, 0.2, np.float32)

    res = evaluate([make_frame("signed", 14)], {"flat": flat})
    assert res.pooled["flat"]["retro_contrast_pred"] == pytest.approx(1.0)
    assert res.pooled["flat"]["retro_contrast_ratio"] < 0.4


def test_retro_contrast_follows_the_label_set_materials_not_a_class_number():
    # Class 256 is a retro-reflective construction cone in Voxelscape but a moving tram in
    # SemanticKITTI: the same labelled points are retro-reflectors in one set only.
    kitti = make_frame("cones", 15, sign=False, relabel=(256, 200))
    voxelscape = EvalFrame(
        "cones",
        kitti.xyz,
        kitti.intensity,
        kitti.profile,
        kitti.labels,
        "voxelscape",
        kitti.ring,
    )
    as_kitti = evaluate([kitti], {"perfect": perfect}).pooled["perfect"]
    as_voxelscape = evaluate([voxelscape], {"perfect": perfect}).pooled["perfect"]
    assert np.isnan(as_kitti["retro_contrast_real"])
    assert as_voxelscape["retro_contrast_real"] > 0


def test_frames_without_retro_reflectors_report_no_contrast():
    res = evaluate([make_frame("no-sign", 16, sign=False)], {"perfect": perfect})
    assert res.to_json()["pooled"]["perfect"]["retro_contrast_real"] is None


# --- summary -----------------------------------------------------------------------------


def test_the_summary_says_which_methods_the_generator_beats(result):
    beats = result.summary["beats"]
    assert set(beats) == {"mae_reflectivity", "cell_w1_reflectivity"}
    for metric in beats:
        assert beats[metric]["worse"] is True
        assert beats[metric]["oracle"] is False
        assert beats[metric]["unchanged"] is True
        assert beats[metric]["histogram_global"] is False
        assert "generator" not in beats[metric]
    assert result.summary["best"]["mae_reflectivity"] == ["oracle"]


def test_without_a_generator_the_summary_compares_nothing(heldout):
    res = evaluate(heldout[:1], {"perfect": perfect})
    assert res.summary["subject"] is None
    assert res.summary["beats"] == {}


def test_class_ids_mask_instance_bits_exactly_where_the_materials_table_does():
    label = np.array([10 | (3 << 16)], dtype=np.int64)  # class 10 with instance 3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unknown ids warn once; not the point here
        for label_set in LABEL_SETS:
            expected = reflectance_for_labels(label, label_set)
            assert reflectance_for_labels(class_ids(label, label_set), label_set) == expected


# --- input checks ------------------------------------------------------------------------


def test_frames_reject_labels_of_the_wrong_shape_or_without_a_label_set():
    xyz = np.ones((5, 3), np.float32)
    with pytest.raises(InvalidPointsError, match="labels has shape"):
        EvalFrame("f", xyz, np.zeros(5, np.float32), HDL64, np.zeros(4, int), "semantickitti")
    with pytest.raises(ConfigError, match="label_set"):
        EvalFrame("f", xyz, np.zeros(5, np.float32), HDL64, np.zeros(5, int), None)


def test_evaluate_rejects_a_method_output_of_the_wrong_shape(heldout):
    with pytest.raises(InputDataError, match="method 'short' returned shape"):
        evaluate(heldout[:1], {"short": lambda f: f.intensity[:-1]})
    with pytest.raises(InputDataError, match="named 'held-0'"):
        evaluate([heldout[0], heldout[0]], {"perfect": perfect})


# --- report and figures ------------------------------------------------------------------


def test_write_report_writes_json_and_a_markdown_table(result, tmp_path):
    paths = write_report(
        result,
        tmp_path / "report",
        title="synth-to-kitti on 2 frames",
        context={"model": "synth-to-kitti", "split": "held-out", "root": tmp_path},
    )
    assert [p.name for p in paths] == ["eval.json", "eval.md"]
    data = json.loads(paths[0].read_text())
    assert data["context"]["root"] == str(tmp_path)
    assert set(data["pooled"]) == set(result.methods)
    assert data["pooled"]["oracle"]["mae_encoded"] == 0.0
    assert data["summary"]["beats"]["mae_reflectivity"]["worse"] is True
    md = paths[1].read_text()
    assert "| method | MAE (encoded) |" in md
    assert "|---|---:|" in md
    assert "| oracle | **0** |" in md
    assert "- generator beats worse on MAE" in md
    assert "- generator does not beat oracle on cell W1" in md
    # The fixture's intensities follow the physics law exactly: the fitted law wins there.
    assert "## Targets" in md and "- mae_vs_median: met, " in md
    assert "- mae_vs_fitted_law: MISSED, " in md
    assert [r["target"] for r in data["summary"]["targets"]][:3] == [
        "mae_vs_median",
        "mae_vs_fitted_law",
        "cell_w1",
    ]


def test_to_json_rounds_floats_and_writes_missing_values_as_null(result):
    data = result.to_json()
    text = json.dumps(data, allow_nan=False)  # raises on NaN
    mae = data["pooled"]["generator"]["mae_reflectivity"]
    assert len(repr(mae).replace("0.", "").lstrip("0")) <= 8
    assert "NaN" not in text


def test_range_panels_writes_a_png_for_a_64_row_frame(result, heldout, tmp_path):
    frame = heldout[0]
    out = eval_figures.range_panels(
        frame,
        {"generator": result.predictions[frame.name]["generator"]},
        tmp_path / "figs" / "panels.png",
    )
    data = out.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width > 2 * height  # wide panels suit a 64 x 2048 image


def test_histograms_write_pngs_for_a_frame_and_for_pooled_values(result, heldout, tmp_path):
    frame = heldout[0]
    one = eval_figures.histograms(
        frame, result.predictions[frame.name], tmp_path / "frame_hist.png"
    )
    real, preds, classes = result.pooled_values()
    pooled = eval_figures.histograms(
        real,
        preds,
        tmp_path / "pooled_hist.png",
        classes=classes,
        class_names=result.class_names,
        profile=HDL64,
        title="pooled",
    )
    for path in (one, pooled):
        assert path.read_bytes()[:8] == PNG_SIGNATURE
