"""The fitted physics law, the baselines fitted on training frames, splits by place and the
choice of a model on validation frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from lads.errors import ConfigError
from lads.intensity import fitted_physics
from lads.intensity.baselines import InSampleBound, fit_baselines
from lads.intensity.evaluate import EvalFrame, class_ids, evaluate, physics_image
from lads.intensity.features import channel_names, frame_image
from lads.intensity.law_reference import TorchLaw
from lads.intensity.splits import merged_view, split_frames
from lads.sensors.profile import load_profile
from lads.synth import synth_frame

HDL64 = load_profile("hdl64e")
TRUE = {"b1": 0.6, "b2": -0.4, "sigma": 0.5, "a": {40: -2.0, 50: -1.2, 70: -1.6}}


def law_data(n: int, seed: int, noise: float = 0.05):
    rng = np.random.default_rng(seed)
    group = rng.choice(list(TRUE["a"]), n)
    r = rng.uniform(3, 70, n)
    cos = rng.uniform(0.05, 1.0, n)
    a = np.array([TRUE["a"][g] for g in group])
    ln = (
        a
        + TRUE["b1"] * np.log(r)
        + TRUE["b2"] * r / 10
        + np.log(fitted_physics.oren_nayar(cos, TRUE["sigma"]))
    )
    refl = np.exp(ln + rng.laplace(0, noise, n)) - 0.005
    return group, r, cos, np.maximum(refl, 0)


def test_the_law_recovers_its_parameters_from_noisy_data():
    group, r, cos, refl = law_data(20000, 0)
    law = fitted_physics.fit(group, r, cos, refl, floor=0.005)
    assert law.b1 == pytest.approx(TRUE["b1"], abs=0.03)
    assert law.b2 == pytest.approx(TRUE["b2"], abs=0.03)
    assert law.sigma_rad == pytest.approx(TRUE["sigma"], abs=0.1)
    for g, a in TRUE["a"].items():
        assert law.intercepts[g] == pytest.approx(a, abs=0.08)
    again = fitted_physics.FittedPhysics.from_json(law.to_json())
    assert np.allclose(again.predict(group, r, cos), law.predict(group, r, cos))


def test_lambert_is_oren_nayar_without_roughness_and_rough_surfaces_stay_bright():
    cos = np.linspace(0.01, 1, 50)
    assert np.allclose(fitted_physics.oren_nayar(cos, 0.0), cos)
    assert fitted_physics.oren_nayar(np.array([0.1]), 1.0)[0] > 0.1 * 3


def test_rare_groups_take_the_pooled_intercept():
    group, r, cos, refl = law_data(5000, 1)
    group[:10] = 999  # ten points of a group: too few to fit on its own
    law = fitted_physics.fit(group, r, cos, refl, floor=0.005)
    assert 999 not in law.intercepts
    assert law.ln_predict([999], [10.0], [0.5])[0] == pytest.approx(
        law.pooled_intercept
        + law.b1 * np.log(10)
        + law.b2
        + np.log(fitted_physics.oren_nayar(np.array([0.5]), law.sigma_rad))[0]
    )
    # Unknown, negative (no material) and fitted groups side by side.
    known = next(iter(law.intercepts))
    a = law.intercept_of(np.array([-1, known, 999, 10**6]))
    assert a.tolist() == [law.pooled_intercept, law.intercepts[known]] + [law.pooled_intercept] * 2
    negative = fitted_physics.fit(group - 100, r, cos, refl, floor=0.005)  # ids below zero
    assert negative.intercept_of(np.array([known - 100, -1000]))[0] == law.intercepts[known]


def test_the_torch_law_equals_the_numpy_law_on_a_frame():
    group, r, cos, refl = law_data(4000, 2)
    elevation = np.asarray(HDL64.elevation_deg)[::8][np.arange(len(r)) % 8]  # 8 of its lasers
    law = fitted_physics.fit(
        group % 5, r, cos, refl, floor=0.005, elevation_deg=elevation
    )  # groups as material ids; fmt: skip
    assert law.laser_curves
    frame = synth_frame("hdl64e", frames=1, seed=1, index=0, azimuth_bins=256)
    fi = frame_image(frame.xyz, HDL64, labels=frame.labels, label_set="semantickitti")
    names = channel_names(False)
    raw = torch.from_numpy(fi.inputs)[None]
    torch_ln = TorchLaw.of(law, names).ln_reference(raw, torch.zeros(1))[0, 0].numpy()
    occ = fi.inputs[names.index("mask")] > 0
    x = {
        n: fi.inputs[names.index(n)][occ]
        for n in ("ln_range", "cos_incidence", "material", "elevation")
    }
    numpy_ln = law.ln_predict(
        np.rint(x["material"]).astype(int) - 1,
        np.exp(x["ln_range"]),
        x["cos_incidence"],
        0.0,
        x["elevation"] * 30.0,
    )
    assert np.allclose(torch_ln[occ], numpy_ln, atol=1e-4)


def test_ego_returns_neither_move_the_fit_nor_blow_up_near_the_sensor():
    group, r, cos, refl = law_data(20000, 0)
    group = np.vectorize({40: 3, 50: 5, 70: 7}.get)(group)  # as material indices
    ego = 3000  # dark returns from the car body, 0.05-0.3 m from the sensor
    group = np.concatenate([group, np.full(ego, 7)])
    r = np.concatenate([r, np.linspace(0.05, 0.3, ego)])
    cos, refl = np.concatenate([cos, np.full(ego, 0.4)]), np.concatenate([refl, np.full(ego, 0.02)])
    law = fitted_physics.fit(group, r, cos, refl, floor=0.005)
    assert law.b1 == pytest.approx(TRUE["b1"], abs=0.03)
    assert law.range_min_m >= 3.0 and law.range_max_m <= 70.0
    near = law.ln_predict([7, 7], [0.1, law.range_min_m], [0.4, 0.4])
    assert near[0] == near[1]  # clamped to the fitted support, not extrapolated
    # The torch law agrees with numpy there too, and on pixels without a material.
    names = channel_names(False)
    raw = torch.zeros(1, len(names), 1, 4)
    raw[0, names.index("ln_range"), 0] = torch.log(torch.tensor([0.1, 5.0, 500.0, 20.0]))
    raw[0, names.index("cos_incidence"), 0] = torch.tensor([0.4, 0.9, 0.5, 0.7])
    raw[0, names.index("material"), 0] = torch.tensor([8.0, 0.0, 4.0, 999.0])
    torch_ln = TorchLaw.of(law, names).ln_reference(raw, torch.zeros(1))[0, 0, 0].numpy()
    numpy_ln = law.ln_predict([7, -1, 3, 998], [0.1, 5.0, 500.0, 20.0], [0.4, 0.9, 0.5, 0.7])
    assert np.allclose(torch_ln, numpy_ln, atol=1e-4)


def _frame(name: str, seed: int) -> EvalFrame:
    f = synth_frame("hdl64e", frames=1, seed=seed, index=0, azimuth_bins=256)
    return EvalFrame(name, f.xyz, f.intensity, HDL64, f.labels, "semantickitti")


def test_per_class_median_and_fitted_physics_are_fitted_on_the_reference_frames_only():
    train, test = _frame("train", 1), _frame("test", 2)
    methods = fit_baselines([train])
    cls = class_ids(train.labels, "semantickitti")
    refl = HDL64.intensity.to_reflectivity(train.intensity)
    road = int(np.bincount(cls).argmax())
    got = methods["per_class_median"](test)[class_ids(test.labels, "semantickitti") == road]
    assert np.allclose(got, HDL64.intensity.from_reflectivity([np.median(refl[cls == road])]))
    law = methods["fitted_physics"].law
    assert law.points == train.n_points and set(law.intercepts) <= set(np.unique(cls).tolist())


def test_the_in_sample_bound_beats_the_per_class_median_on_its_own_points():
    frames = [_frame("a", 3), _frame("b", 4)]
    methods = fit_baselines(frames)
    methods["bound_in_sample"] = InSampleBound.of(frames)
    result = evaluate(frames, methods)
    mae = {m: row["mae_reflectivity"] for m, row in result.pooled.items()}
    assert mae["bound_in_sample"] < mae["per_class_median"]
    assert "bound_in_sample" not in result.summary["best"]["mae_reflectivity"]
    assert physics_image(frames[0]).range_m.shape == (frames[0].n_points,)


def test_splits_are_disjoint_and_every_pattern_matches():
    names = [f"s/{i:02d}.bin" for i in range(10)]
    split = {"train": ("s/0[0-5].bin",), "validation": ("s/0[6-7].bin",), "test": ("s/0[89].bin",)}
    got = split_frames(names, split, "here")
    assert [len(got[k]) for k in ("train", "validation", "test")] == [6, 2, 2]
    assert split_frames(names, {}, "here")["train"] == names
    with pytest.raises(ConfigError, match="matches no frame"):
        split_frames(names, {"test": ("x/*.bin",)}, "here")
    with pytest.raises(ConfigError, match="both split.train and split.test"):
        split_frames(names, {"train": ("s/*",), "test": ("s/09.bin",)}, "here")


def test_a_merged_view_links_every_root_and_refuses_collisions(tmp_path: Path):
    for root, name in (("a", "x/1.bin"), ("b", "y/2.bin"), ("c", "x/1.bin")):
        (tmp_path / root / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / root / name).write_text(root)
    view = merged_view([tmp_path / "a", tmp_path / "b"])
    assert (view / "x/1.bin").read_text() == "a" and (view / "y/2.bin").read_text() == "b"
    with pytest.raises(ConfigError, match="two dataset roots"):
        merged_view([tmp_path / "a", tmp_path / "c"])


LASERS_DEG = np.array([-20.0, -12.0, -6.0, -2.0, 1.0])
# Each laser's own calibration: a gain, and a bend near or far (ln-intensity deviation).
LASER_DEVIATION = {
    0: lambda r: 0.3 + 0.0 * r,
    1: lambda r: -0.25 + 0.0 * r,
    2: lambda r: 0.2 * np.log(r / 10),
    3: lambda r: -0.3 * np.exp(-r / 6),
    4: lambda r: 0.0 * r,
}


def laser_data(n: int, seed: int):
    group, r, cos, _ = law_data(n, seed)
    rng = np.random.default_rng(seed + 100)
    laser = rng.integers(0, len(LASERS_DEG), n)
    deviation = np.zeros(n)
    for k, fn in LASER_DEVIATION.items():
        deviation[laser == k] = fn(r[laser == k])
    a = np.array([TRUE["a"][g] for g in group])
    ln = (
        a
        + TRUE["b1"] * np.log(r)
        + TRUE["b2"] * r / 10
        + deviation
        + np.log(fitted_physics.oren_nayar(cos, TRUE["sigma"]))
    )
    refl = np.maximum(np.exp(ln + rng.laplace(0, 0.05, n)) - 0.005, 0)
    return group, r, cos, refl, LASERS_DEG[laser], deviation


def test_each_lasers_range_response_is_fitted_and_looked_up_by_elevation():
    group, r, cos, refl, elevation, deviation = laser_data(40000, 5)
    plain = fitted_physics.fit(group, r, cos, refl, floor=0.005)
    law = fitted_physics.fit(group, r, cos, refl, floor=0.005, elevation_deg=elevation)
    assert not plain.laser_curves
    assert law.laser_elevation_deg == tuple(LASERS_DEG)
    truth = np.log(refl + 0.005)
    err_plain = np.abs(plain.ln_predict(group, r, cos) - truth).mean()
    err_laser = np.abs(law.ln_predict(group, r, cos, elevation_deg=elevation) - truth).mean()
    assert err_laser < 0.6 * err_plain
    # Recovered up to the shared law: the curve differences between lasers match the truth.
    probe = np.array([4.0, 10.0, 40.0])
    for k in (0, 1, 2, 3):
        got = law.laser_term(probe, np.full(3, LASERS_DEG[k])) - law.laser_term(
            probe, np.full(3, LASERS_DEG[4])
        )
        assert np.allclose(got, LASER_DEVIATION[k](probe), atol=0.06), k
    # A beam between two lasers takes the nearer one; no elevation, no laser term.
    assert np.array_equal(
        fitted_physics.nearest_laser(LASERS_DEG, [-19.0, -9.5, 5.0, -30.0]), [0, 1, 4, 0]
    )
    assert law.laser_term(probe, None).tolist() == [0.0, 0.0, 0.0]
    again = fitted_physics.FittedPhysics.from_json(law.to_json())
    assert np.allclose(
        again.ln_predict(group, r, cos, elevation_deg=elevation),
        law.ln_predict(group, r, cos, elevation_deg=elevation),
    )


def test_a_laser_with_too_few_points_keeps_the_shared_law():
    group, r, cos, refl, elevation, _ = laser_data(20000, 6)
    elevation[:10] = 7.0  # a laser seen ten times
    law = fitted_physics.fit(group, r, cos, refl, floor=0.005, elevation_deg=elevation)
    lone = law.laser_elevation_deg.index(7.0)
    assert np.abs(law.laser_curves[lone]).max() < 1e-3


def test_the_hat_basis_interpolates_linearly_and_clamps():
    knots = np.log(np.array([3.0, 10.0, 30.0]))
    x = np.log(np.array([1.0, 3.0, np.sqrt(30.0), 30.0, 100.0]))
    basis, cols = fitted_physics.hat_basis(x, knots)
    values = np.array([1.0, 2.0, 4.0])
    got = (values[cols] * basis).sum(axis=1)
    assert np.allclose(got, [1.0, 1.0, 1.0 + np.log(np.sqrt(30) / 3) / np.log(10 / 3), 4.0, 4.0])


def test_the_compiled_law_sums_are_the_numpy_expression_bit_for_bit():
    group, r, cos, refl, elevation, _ = laser_data(20000, 7)
    law = fitted_physics.fit(group, r, cos, refl, floor=0.005, elevation_deg=elevation)
    r = np.r_[r, 0.01, 1e4, law.range_min_m, law.range_max_m]  # outside and at the support
    group, cos = np.r_[group, 0, 1, 2, 99], np.r_[cos, 0.0, 1.0, 0.5, 0.3]
    elevation = np.r_[elevation, -40.0, 40.0, LASERS_DEG[1], -9.5]
    for alpha in (0.0, 0.013):
        fast = law.ln_predict(group, r, cos, alpha, elevation)
        # An extinction per point takes the numpy expression (no compiled sums).
        slow = law.ln_predict(group, r, cos, np.full(r.shape, alpha), elevation)
        assert np.array_equal(fast.view(np.int64), slow.view(np.int64))
        clamped = np.clip(r, law.range_min_m, law.range_max_m)
        by_hand = (
            law.intercept_of(group)
            + law.b1 * np.log(clamped)
            + law.b2 * clamped / 10.0
            + np.log(fitted_physics.oren_nayar(cos, law.sigma_rad))
            + law.laser_term(clamped, elevation)
            - 2.0 * alpha * clamped
        )
        assert np.array_equal(fast.view(np.int64), by_hand.view(np.int64))


def test_the_compiled_oren_nayar_factor_is_the_numpy_expression_bit_for_bit():
    rng = np.random.default_rng(8)
    for dtype in (np.float32, np.float64):
        c = np.r_[rng.uniform(-0.5, 1.5, 5000), np.nan, 0.0, 1.0, 1e-3, np.inf].astype(dtype)
        for sigma in (0.0, 0.3, 1.2):
            a, b = fitted_physics.oren_nayar_coefficients(sigma)
            clipped = np.clip(c.astype(np.float64), fitted_physics.COS_FLOOR, 1.0)
            want = a * clipped + b * (1.0 - clipped**2)
            got = fitted_physics.oren_nayar(c, sigma)
            assert np.array_equal(got.view(np.int64), want.view(np.int64))
    assert fitted_physics.oren_nayar(np.full((4, 5), 0.5), 0.3).shape == (4, 5)
    assert fitted_physics.oren_nayar([1, 0], 0.0).tolist() == [1.0, fitted_physics.COS_FLOOR]
