"""The learned intensity: features, weight files, every point's value, encodings, errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from lads.errors import ConfigError, InvalidPointsError, LadsError, ModelError
from lads.intensity.checkpoint import ModelMeta, TargetSpec, build_generator, load_model, save_model
from lads.intensity.features import FEATURE_VERSION, channel_names, frame_image
from lads.intensity.layers import WrapConv
from lads.intensity.predict import MAX_SHARED_RATIO, predict_points
from lads.physics.materials import material_names
from lads.physics.projection import project
from lads.sensors.profile import load_profile
from lads.synth import synth_frame

HDL64 = load_profile("hdl64e")
HDL32 = load_profile("hdl32e")


def _meta(kind: str = "sensor", sensor: str = "hdl64e", **changes) -> ModelMeta:
    styles = kind == "weather"
    targets = (
        {s: TargetSpec("wads64", -2.0, 1.0, 0.002, 0.5) for s in ("snow", "fog")}
        if styles
        else {"kitti": TargetSpec(sensor, -1.5, 0.8, 0.005, 1.2)}
    )
    values = dict(
        name="tiny",
        kind=kind,
        channels=channel_names(styles),
        feature_version=FEATURE_VERSION,
        range_exponent=1.0,
        base=4,
        blocks=1,
        targets=targets,
        calibration={"hdl64e": 1.2, "wads64": 0.5},
        materials=material_names(),
    )
    values.update(changes)
    return ModelMeta(**values)


def tiny_model(tmp_path, kind: str = "sensor", seed: int = 0, **changes):
    """A small random generator saved as a real weight file, and its path."""
    torch.manual_seed(seed)
    meta = _meta(kind, **changes)
    gen = build_generator(meta)
    with torch.no_grad():
        for p in gen.parameters():
            p.normal_(0, 0.1)
    gen.norm.set_stats(
        {"ln_range": 2.5, "cos_incidence": 0.4, "reflectance": 0.35, "ln_physics": -4.0},
        {"ln_range": 0.8, "cos_incidence": 0.25, "reflectance": 0.2, "ln_physics": 1.0},
    )
    path = tmp_path / f"tiny-{kind}.pt"
    save_model(path, meta, gen)
    return path


@pytest.fixture(scope="module")
def street():
    f = synth_frame("hdl64e", frames=1, seed=3, index=0, azimuth_bins=512)
    return f


def test_features_have_one_channel_per_name_and_zero_on_empty_pixels(street):
    fi = frame_image(
        street.xyz,
        HDL64,
        labels=street.labels,
        label_set="semantickitti",
        ring=street.ring,
        intensity=street.intensity,
    )
    assert fi.inputs.shape == (len(channel_names(False)), 64, HDL64.range_image_width)
    empty = ~fi.mask
    assert np.all(fi.inputs[:, empty] == 0)
    assert fi.target is not None and np.all(fi.target[empty] == 0)
    assert fi.physics.shape == (len(street.xyz),)


def test_physics_reference_comes_from_materials_not_the_measured_intensity(street):
    a = frame_image(
        street.xyz,
        HDL64,
        labels=street.labels,
        label_set="semantickitti",
        intensity=street.intensity,
    )
    b = frame_image(
        street.xyz,
        HDL64,
        labels=street.labels,
        label_set="semantickitti",
        intensity=np.zeros_like(street.intensity),
    )
    assert np.array_equal(a.inputs, b.inputs)


def test_every_point_gets_a_value_and_sharers_follow_their_own_physics(tmp_path):
    # 3000 beams per ring in 2048 columns: about a third of the points share a pixel.
    dense = synth_frame("hdl64e", frames=1, seed=3, index=0, azimuth_bins=3000)
    model = load_model(tiny_model(tmp_path))
    pred = predict_points(
        model, dense.xyz, HDL64, labels=dense.labels, label_set="semantickitti", ring=dense.ring
    )
    n = len(dense.xyz)
    assert pred.reflectivity.shape == pred.encoded.shape == (n,)
    assert np.isfinite(pred.reflectivity).all()
    image = project(dense.xyz, HDL64, channel=dense.ring)
    owner = image.index[image.row, image.col]
    sharers = np.flatnonzero(owner != np.arange(n))
    assert np.array_equal(pred.owner, owner == np.arange(n))
    assert sharers.size > n // 5
    fi = frame_image(
        dense.xyz, HDL64, labels=dense.labels, label_set="semantickitti", ring=dense.ring
    )
    f = model.meta.targets["kitti"].floor
    ln_ratio = np.log(fi.physics[sharers] + 1e-6) - np.log(fi.physics[owner[sharers]] + 1e-6)
    expected = np.log(pred.reflectivity[owner[sharers]] + f) + np.clip(
        ln_ratio, -np.log(MAX_SHARED_RATIO), np.log(MAX_SHARED_RATIO)
    )
    got = np.log(np.maximum(pred.reflectivity[sharers], 0) + f)
    ok = pred.reflectivity[sharers] > 0
    assert ok.mean() > 0.9 and np.allclose(got[ok], expected[ok], atol=1e-4)


def test_points_sharing_a_pixel_get_distinct_physics_scaled_values(tmp_path):
    # Two points on one ray direction-bin: the nearer owns the pixel, the farther (same
    # material, twice the range) must get about half the owner's value with n = 1.
    model = load_model(tiny_model(tmp_path))
    base = synth_frame("hdl64e", frames=1, seed=3, index=0, azimuth_bins=512)
    xyz = np.concatenate([base.xyz, base.xyz[:1] * 2.0]).astype(np.float32)
    labels = np.concatenate([base.labels, base.labels[:1]])
    ring = np.concatenate([base.ring, base.ring[:1]])
    pred = predict_points(model, xyz, HDL64, labels=labels, label_set="semantickitti", ring=ring)
    near, far = pred.reflectivity[0], pred.reflectivity[-1]
    assert pred.owner[0] and not pred.owner[-1]
    f = model.meta.targets["kitti"].floor
    assert np.log(far + f) == pytest.approx(np.log(near + f) + np.log(0.5), abs=0.05)


def test_with_a_fitted_law_sharers_take_the_law_at_their_own_inputs(tmp_path):
    """In a residual model a sharer gets its pixel's value moved by the law's difference
    between itself and the owner (its own material, range, incidence and laser), not by the
    literature reflectance ratio."""
    from lads.intensity import fitted_physics

    dense = synth_frame("hdl64e", frames=1, seed=3, index=0, azimuth_bins=3000)
    elevations = tuple(float(v) for v in HDL64.elevation_deg)
    curves = tuple((0.1 * (k % 3), -0.05 * (k % 5), 0.0) for k in range(len(elevations)))
    law = fitted_physics.FittedPhysics(
        {i: -1.5 + 0.2 * i for i in range(10)},
        -1.4,
        0.5,
        -0.3,
        0.4,
        0.005,
        3.0,
        80.0,
        laser_elevation_deg=elevations,
        laser_knots_ln=tuple(np.log([3.0, 10.0, 80.0])),
        laser_curves=curves,
    )
    spec = TargetSpec("hdl64e", -1.5, 0.8, 0.005, 1.2, law=law.to_json())
    save_model(tmp_path / "r.pt", _meta(targets={"kitti": spec}), build_generator(_meta()))
    pred = predict_points(
        load_model(tmp_path / "r.pt"),
        dense.xyz,
        HDL64,
        labels=dense.labels,
        label_set="semantickitti",
        ring=dense.ring,
    )
    fi = frame_image(
        dense.xyz, HDL64, labels=dense.labels, label_set="semantickitti", ring=dense.ring
    )
    ln_law = law.ln_predict(fi.material, fi.range_m, fi.cos_incidence, 0.0, fi.elevation_deg)
    owner = fi.image.index[fi.image.row, fi.image.col]
    sharers = np.flatnonzero(owner != np.arange(len(owner)))
    limit = np.log(MAX_SHARED_RATIO)
    expected = np.log(pred.reflectivity[owner[sharers]] + 0.005) + np.clip(
        ln_law[sharers] - ln_law[owner[sharers]], -limit, limit
    )
    got = np.log(pred.reflectivity[sharers] + 0.005)
    ok = (pred.reflectivity[sharers] > 0) & (pred.reflectivity[owner[sharers]] > 0)
    assert sharers.size > 1000 and ok.mean() > 0.9
    assert np.allclose(got[ok], expected[ok], atol=1e-4)
    # Not the physics ratio: the two rules differ where a sharer's material is not its
    # owner's (the law's intercepts are not the literature reflectances).
    ln_phys = np.log(fi.physics + 1e-6)
    phys_rule = np.log(pred.reflectivity[owner[sharers]] + 0.005) + np.clip(
        ln_phys[sharers] - ln_phys[owner[sharers]], -limit, limit
    )
    other = fi.material[sharers] != fi.material[owner[sharers]]
    assert other.sum() > 50 and np.mean(np.abs(phys_rule - got)[other] > 0.05) > 0.5


def test_output_is_in_the_target_encoding(tmp_path, street):
    kitti = load_model(tiny_model(tmp_path))
    pred = predict_points(
        kitti, street.xyz, HDL64, labels=street.labels, label_set="semantickitti", ring=street.ring
    )
    steps = pred.encoded / 0.01
    assert np.allclose(steps, np.rint(steps), atol=1e-4) and pred.encoded.max() <= 0.99
    nusc_path = tiny_model(tmp_path / "n", sensor="hdl32e")
    nusc = load_model(nusc_path)
    pred32 = predict_points(
        nusc, street.xyz, HDL64, labels=street.labels, label_set="semantickitti", ring=street.ring
    )
    assert np.array_equal(pred32.encoded, np.rint(pred32.encoded))
    assert pred32.encoded.max() <= 255


def test_the_output_head_reaches_the_top_of_the_encoding(tmp_path, street):
    # No tanh cap: a large output must decode to the brightest code (retro-reflectors).
    path = tiny_model(tmp_path)
    model = load_model(path)
    with torch.no_grad():
        model.generator.linear.bias.fill_(50.0)
    pred = predict_points(
        model, street.xyz, HDL64, labels=street.labels, label_set="semantickitti", ring=street.ring
    )
    assert pred.encoded.max() == pytest.approx(0.99)


def test_missing_weights_name_the_file(tmp_path):
    with pytest.raises(ModelError, match="not found"):
        load_model(tmp_path / "nope.pt")


def test_corrupt_weights_are_refused(tmp_path):
    path = tiny_model(tmp_path)
    data = bytearray(path.read_bytes())
    path.write_bytes(bytes(data[: len(data) // 2]))
    with pytest.raises(ModelError, match=str(path.name)):
        load_model(path)


def test_altered_normalisation_statistics_are_refused(tmp_path):
    path = tiny_model(tmp_path)
    blob = torch.load(path, weights_only=True)
    blob["state_dict"]["norm.mean"][0] += 1.0
    torch.save(blob, path)
    with pytest.raises(ModelError, match="normalisation statistics"):
        load_model(path)


def test_weights_of_another_feature_version_are_refused(tmp_path):
    path = tiny_model(tmp_path, feature_version="0")
    with pytest.raises(ModelError, match="features v0"):
        load_model(path)


def test_weights_trained_with_another_material_list_are_refused(tmp_path):
    path = tiny_model(tmp_path, materials=("asphalt", "retroreflective_sheeting"))
    with pytest.raises(ModelError, match="materials.yaml"):
        load_model(path)


def test_the_material_channel_tells_apart_materials_of_equal_reflectance():
    """Lane paint and clothing are both 0.60: the reflectance channel cannot separate them,
    the material channel must (a sensor answers them differently); no label is unknown."""
    xyz = np.array([[10.0, 0.0, -1.0], [0.0, 10.0, -1.0], [-10.0, 0.0, -1.0]])
    labels = np.array([60, 30, 0], dtype=np.uint32)  # lane-marking, person, unlabeled
    fi = frame_image(xyz, HDL64, labels=labels, label_set="semantickitti")
    names, ch = material_names(), fi.channels
    owned = fi.image.index[fi.image.row, fi.image.col] == np.arange(3)
    assert owned.all()
    rho = fi.inputs[ch.index("reflectance"), fi.image.row, fi.image.col]
    material = fi.inputs[ch.index("material"), fi.image.row, fi.image.col].astype(int) - 1
    assert rho[0] == rho[1]
    assert [names[m] for m in material] == ["paint_white", "fabric_clothing", "unknown"]
    unlabelled = frame_image(xyz, HDL64)
    assert set(unlabelled.inputs[ch.index("material")][unlabelled.mask]) == {
        names.index("unknown") + 1.0
    }


def test_a_generator_learns_a_response_that_reflectance_alone_cannot_carry():
    """Two materials of equal reflectance and geometry, one read 5x brighter by the sensor
    (retro-reflection, gloss): every physics channel is the same for both, so only the
    material embedding can separate them, and it does."""
    from lads.intensity.features import NORMALISED_CHANNELS
    from lads.intensity.model import Generator

    names = channel_names(False)
    raw = torch.zeros(1, len(names), 8, 32)
    raw[:, names.index("mask")] = 1.0
    raw[:, names.index("reflectance")] = 0.6
    raw[:, names.index("ln_range")] = 2.0
    raw[:, names.index("cos_incidence")] = 0.5
    bright = torch.zeros(8, 32, dtype=torch.bool)
    bright[:, ::2] = True  # alternate columns: no spatial context tells them apart
    raw[:, names.index("material")] = torch.where(bright, 12.0, 17.0)
    target = torch.where(bright, 1.0, -1.0)[None, None] * 0.8  # z units: ln 5 apart at std 1
    mask = raw[:, names.index("mask")][:, None]

    def fitted_gap() -> float:
        torch.manual_seed(0)
        g = Generator(names, NORMALISED_CHANNELS, base=4, blocks=1, materials=len(material_names()))
        opt = torch.optim.Adam(g.parameters(), lr=0.01)
        for _ in range(150):
            opt.zero_grad()
            loss = (g(raw, mask) - target).abs().mean()
            loss.backward()
            opt.step()
        with torch.no_grad():
            out = g(raw, mask)[0, 0]
        return float(out[bright].mean() - out[~bright].mean())

    assert fitted_gap() > 1.4  # of the 1.6 the data ask for


def test_a_material_the_model_never_learnt_adds_nothing(tmp_path, street):
    """The embedding table starts at zero: untouched rows leave the physics channels alone."""
    from lads.intensity.features import NORMALISED_CHANNELS
    from lads.intensity.model import Generator

    names = channel_names(False)
    torch.manual_seed(1)
    g = Generator(names, NORMALISED_CHANNELS, base=4, blocks=1, materials=len(material_names()))
    with torch.no_grad():  # a trained-looking network, but an embedding row never updated
        for name, p in g.named_parameters():
            if "material_embedding" not in name:
                p.normal_(0, 0.1)
    fi = frame_image(street.xyz, HDL64, labels=street.labels, label_set="semantickitti")
    raw = torch.from_numpy(fi.inputs)[None]
    mask = raw[:, names.index("mask")][:, None]
    other = raw.clone()
    other[:, names.index("material")] = torch.where(mask[:, 0] > 0, 3.0, 0.0)
    with torch.no_grad():
        out = g(raw, mask)
        assert out.abs().max() > 0.01  # not zero by construction
        assert torch.equal(out, g(other, mask))


def test_weather_model_refuses_a_style_it_was_not_trained_for(tmp_path, street):
    model = load_model(tiny_model(tmp_path, kind="weather"))
    with pytest.raises(ModelError, match="rain"):
        predict_points(model, street.xyz, HDL64, target="rain")


def test_weather_output_needs_a_calibration_for_the_output_sensor(tmp_path, street):
    model = load_model(tiny_model(tmp_path, kind="weather"))
    ok = predict_points(model, street.xyz, HDL64, target="snow", output_profile=HDL64)
    assert ok.encoded.shape == (len(street.xyz),)
    with pytest.raises(ModelError, match="no calibration for sensor 'hdl32e'"):
        predict_points(model, street.xyz, HDL64, target="snow", output_profile=HDL32)


def test_a_frame_that_is_not_a_scan_of_the_profile_is_refused(tmp_path, street):
    model = load_model(tiny_model(tmp_path))
    tilted = street.xyz.copy()
    tilted[:, 2] += 40.0  # everything far above the HDL-64E's field of view
    with pytest.raises(InvalidPointsError, match="field of view"):
        predict_points(model, tilted, HDL64)


def test_style_without_style_channels_is_a_config_error(street):
    with pytest.raises(ConfigError):
        frame_image(street.xyz, HDL64, style="snow")


def test_every_error_is_a_lads_error():
    assert issubclass(ModelError, LadsError)


@pytest.mark.parametrize("kernel", [1, 3, 5])
@pytest.mark.parametrize("stride", [1, 2])
@pytest.mark.parametrize("width", [8, 13, 64])
def test_wrap_conv_equals_a_convolution_of_the_circularly_padded_image(kernel, stride, width):
    """Azimuth wraps (circular), elevation is zero-padded; values and gradients alike."""
    torch.manual_seed(kernel * 100 + stride * 10 + width)
    conv = WrapConv(3, 4, kernel, stride).double()
    x = torch.randn(2, 3, 6, width, dtype=torch.float64, requires_grad=True)
    p = (kernel - 1) // 2
    padded = F.pad(F.pad(x, (p, p, 0, 0), mode="circular"), (0, 0, p, p))
    expected = conv.conv(padded)
    got = conv(x)
    assert got.shape == expected.shape
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-12)
    grads = torch.autograd.grad((got**2).sum(), [x, conv.conv.weight])
    expected_grads = torch.autograd.grad((expected**2).sum(), [x, conv.conv.weight])
    for g, e in zip(grads, expected_grads, strict=True):
        torch.testing.assert_close(g, e, rtol=0, atol=1e-10)


def test_a_residual_generator_adds_its_correction_to_the_fitted_law(tmp_path, street):
    """The same generator with and without a law: at every pixel owner the residual model's
    ln(I + f) is the plain one's plus the law's (ln I_law + f) - log_mean."""
    from lads.intensity import fitted_physics

    law = fitted_physics.FittedPhysics(
        {i: -1.5 + 0.05 * i for i in range(10)}, -1.4, 0.5, -0.3, 0.4, 0.005
    )
    spec = TargetSpec("hdl64e", -1.5, 0.8, 0.005, 1.2)
    torch.manual_seed(0)
    gen = build_generator(_meta())
    models = {}
    residual = dataclasses.replace(spec, law=law.to_json())
    for name, target in (("plain", spec), ("residual", residual)):
        meta = _meta(targets={"kitti": target})
        save_model(tmp_path / f"{name}.pt", meta, gen)
        models[name] = load_model(tmp_path / f"{name}.pt")
    preds = {
        k: predict_points(
            m, street.xyz, HDL64, labels=street.labels, label_set="semantickitti", ring=street.ring
        )
        for k, m in models.items()
    }
    fi = frame_image(
        street.xyz, HDL64, labels=street.labels, label_set="semantickitti", ring=street.ring
    )
    material = np.rint(fi.inputs[channel_names(False).index("material")]).astype(int) - 1
    own = preds["plain"].owner
    ln_law = law.ln_predict(
        material[fi.image.row[own], fi.image.col[own]], fi.range_m[own], fi.cos_incidence[own]
    )
    f = spec.floor
    shift = np.log(preds["residual"].reflectivity[own] + f) - np.log(
        preds["plain"].reflectivity[own] + f
    )
    unclipped = (preds["plain"].reflectivity[own] > 0) & (preds["residual"].reflectivity[own] > 0)
    assert unclipped.mean() > 0.9
    assert np.allclose(shift[unclipped], (ln_law - spec.log_mean)[unclipped], atol=1e-3)


@pytest.mark.parametrize("blocks", [1, 2, 3])
@pytest.mark.parametrize("width", [16, 96, 256])
def test_inference_wraps_once_and_equals_the_training_forward(blocks, width):
    """`infer` pads azimuth once by the generator's margin instead of in every layer; the
    map must be the same, seam columns included, and narrow images fall back to forward."""
    torch.manual_seed(blocks * 1000 + width)
    meta = _meta(blocks=blocks, base=4)
    gen = build_generator(meta).double().eval()
    with torch.no_grad():
        for p in gen.parameters():
            p.normal_(0, 0.3)
        raw = torch.rand(2, len(meta.channels), 8, width, dtype=torch.float64)
        k = meta.channels.index("mask")
        raw[:, k] = (raw[:, k] > 0.2).double()
        m = meta.channels.index("material")
        raw[:, m] = torch.randint(0, len(material_names()) + 1, raw[:, m].shape).double()
        raw = raw * raw[:, k : k + 1]
        expected = gen(raw, raw[:, k : k + 1])
        got = gen.infer(raw, raw[:, k : k + 1])
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-10)


@pytest.mark.parametrize("architecture", ["unet", "pointwise"])
def test_a_batch_of_frames_gives_each_frame_the_bytes_it_gets_alone(tmp_path, street, architecture):
    """The batched path (several frames per call, as on a GPU) changes no output byte."""
    from lads.intensity import fitted_physics
    from lads.intensity.predict import PointRequest, predict_points_batch

    law = fitted_physics.FittedPhysics(
        {i: -1.5 + 0.2 * i for i in range(10)}, -1.4, 0.5, -0.3, 0.4, 0.005, 3.0, 80.0
    )
    spec = TargetSpec("hdl64e", -1.5, 0.8, 0.005, 1.2, law=law.to_json())
    model = load_model(tiny_model(tmp_path, architecture=architecture, targets={"kitti": spec}))
    other = synth_frame("hdl64e", frames=2, seed=5, index=1, azimuth_bins=512)
    frames = [street, other, street]
    requests = [
        PointRequest(f.xyz, HDL64, labels=f.labels, label_set="semantickitti", ring=f.ring)
        for f in frames
    ]
    batched = predict_points_batch(model, requests)
    for f, b in zip(frames, batched, strict=True):
        alone = predict_points(
            model, f.xyz, HDL64, labels=f.labels, label_set="semantickitti", ring=f.ring
        )
        np.testing.assert_array_equal(b.encoded, alone.encoded)
        np.testing.assert_array_equal(b.reflectivity, alone.reflectivity)


def test_a_pointwise_generator_answers_each_pixel_from_its_own_inputs_only():
    from lads.intensity.model import PointGenerator

    names = channel_names(False)
    torch.manual_seed(0)
    gen = PointGenerator(names, ("ln_range",), width=8, layers=2, materials=len(material_names()))
    raw = torch.rand(1, len(names), 4, 6)
    mask = torch.ones(1, 1, 4, 6)
    law = torch.rand(1, 1, 4, 6)
    assert bool((gen(raw, mask, law) == 0).all())  # untrained: the law alone
    with torch.no_grad():
        for p in gen.parameters():
            p.normal_(0, 0.3)
    before = gen(raw, mask, law)
    raw2, law2 = raw.clone(), law.clone()
    raw2[0, :, 1, 2] += 1.0
    law2[0, 0, 1, 2] += 1.0
    after = gen(raw2, mask, law2)
    changed = (after != before)[0, 0]
    assert bool(changed[1, 2]) and int(changed.sum()) == 1
    # Pixels laid out as a column of points give the same values as the image.
    points = gen(
        raw.reshape(1, len(names), 24, 1), mask.reshape(1, 1, 24, 1), law.reshape(1, 1, 24, 1)
    )
    torch.testing.assert_close(points.reshape(1, 1, 4, 6), before, rtol=0, atol=1e-6)


def test_a_pointwise_generator_without_the_law_input_ignores_the_law_and_says_so(tmp_path):
    from lads.intensity import fitted_physics
    from lads.intensity.model import PointGenerator

    names = channel_names(False)
    torch.manual_seed(0)
    gen = PointGenerator(
        names, ("ln_range",), width=8, layers=2, materials=len(material_names()), law_input=False
    )
    with torch.no_grad():
        for p in gen.parameters():
            p.normal_(0, 0.3)
    raw = torch.rand(1, len(names), 4, 6)
    mask = torch.ones(1, 1, 4, 6)
    law = torch.rand(1, 1, 4, 6)
    out = gen(raw, mask, law)
    torch.testing.assert_close(gen(raw, mask, law * 5 - 2), out, rtol=0, atol=0)
    raw[0, :, 1, 2] += 1.0  # its own inputs still move a point's value
    assert bool((gen(raw, mask, law) != out)[0, 0, 1, 2])
    # The weight file records the choice and loads the same network back.
    fit = fitted_physics.FittedPhysics({0: -1.0}, -1.0, 0.5, -0.3, 0.4, 0.005, 3.0, 80.0)
    spec = TargetSpec("hdl64e", -1.5, 0.8, 0.005, 1.2, law=fit.to_json())
    path = tiny_model(tmp_path, architecture="pointwise", law_input=False, targets={"kitti": spec})
    loaded = load_model(path)
    assert loaded.meta.law_input is False
    assert isinstance(loaded.generator, PointGenerator) and not loaded.generator.law_input


def test_pointwise_inference_in_chunks_equals_the_training_forward(monkeypatch):
    from lads.intensity import model as model_module
    from lads.intensity.model import PointGenerator

    monkeypatch.setattr(model_module, "INFER_CHUNK", 64)  # 1000 points: 16 chunks, one partial
    names = channel_names(False)
    torch.manual_seed(1)
    gen = PointGenerator(names, ("ln_range",), width=8, layers=2, materials=len(material_names()))
    with torch.no_grad():
        for p in gen.parameters():
            p.normal_(0, 0.3)
    raw = torch.rand(1, len(names), 1000, 1) * 3
    mask = torch.ones(1, 1, 1000, 1)
    law = torch.rand(1, 1, 1000, 1)
    with torch.inference_mode():
        got = gen.infer(raw, mask, law)
        want = gen(raw, mask, law)
        assert got.shape == want.shape == (1, 1, 1000, 1)
        torch.testing.assert_close(got, want, rtol=0, atol=1e-6)
        # Every point answered, none twice: a changed point changes its own value only.
        raw[0, :, 700] += 1.0
        changed = (gen.infer(raw, mask, law) != got)[0, 0, :, 0]
        assert changed.nonzero().flatten().tolist() == [700]


@pytest.mark.parametrize(
    ("materials", "law_input", "with_law"),
    [(True, True, True), (True, True, False), (False, True, True), (True, False, True)],
)
def test_the_compiled_input_rows_are_the_torch_inputs_bits(materials, law_input, with_law):
    """Inference on a CPU frame builds the MLP's input rows in one compiled pass; they are
    torch's `_inputs`, bit for bit: z-scores beyond the clamp, material indices outside the
    table, channels not z-scored, without a law or a material table."""
    from lads.intensity.model import PointGenerator

    names = channel_names(False)
    torch.manual_seed(2)
    n_mat = len(material_names()) if materials else 0
    gen = PointGenerator(
        names, ("ln_range", "cos_incidence"), width=8, materials=n_mat, law_input=law_input
    )
    gen.norm.set_stats(
        {"ln_range": 2.3, "cos_incidence": 0.6}, {"ln_range": 0.7, "cos_incidence": 0.01}
    )
    with torch.no_grad():
        for p in gen.parameters():
            p.normal_(0, 0.5)
    raw = torch.randn(1, len(names), 999, 1) * 3
    if materials:
        raw[0, names.index("material")] = torch.randint(-3, n_mat + 5, (999, 1)).float()
    law = torch.randn(1, 1, 999, 1) if with_law else None
    with torch.inference_mode():
        rows = gen._point_rows(raw, None, law)
        want = gen._inputs(raw, None, law)
        assert rows is not None and rows.shape == (999, want.shape[-1])
        assert rows.numpy().tobytes() == want.reshape(999, -1).numpy().tobytes()
        assert bool((want.abs() == 4.0).any())  # the clamp was reached
        torch.testing.assert_close(
            gen.infer(raw, None, law), gen(raw, None, law), rtol=0, atol=1e-6
        )


def test_a_pointwise_model_without_a_fitted_law_is_refused(tmp_path):
    with pytest.raises(ModelError, match="fitted law"):
        load_model(tiny_model(tmp_path, architecture="pointwise"))


def test_a_pointwise_model_gives_every_point_its_own_value(tmp_path):
    from lads.intensity import fitted_physics

    dense = synth_frame("hdl64e", frames=1, seed=3, index=0, azimuth_bins=3000)
    law = fitted_physics.FittedPhysics(
        {i: -1.5 + 0.2 * i for i in range(10)}, -1.4, 0.5, -0.3, 0.4, 0.005, 3.0, 80.0
    )
    spec = TargetSpec("hdl64e", -1.5, 0.8, 0.005, 1.2, law=law.to_json())
    path = tiny_model(tmp_path, architecture="pointwise", base=8, blocks=2, targets={"kitti": spec})
    model = load_model(path)
    pred = predict_points(
        model, dense.xyz, HDL64, labels=dense.labels, label_set="semantickitti", ring=dense.ring
    )
    again = predict_points(
        model, dense.xyz, HDL64, labels=dense.labels, label_set="semantickitti", ring=dense.ring
    )
    assert np.array_equal(pred.encoded, again.encoded)
    fi = frame_image(
        dense.xyz, HDL64, labels=dense.labels, label_set="semantickitti", ring=dense.ring
    )
    ln_law = law.ln_predict(fi.material, fi.range_m, fi.cos_incidence, 0.0, fi.elevation_deg)
    law_z = torch.from_numpy(((ln_law - spec.log_mean) / spec.log_std).astype(np.float32))
    with torch.no_grad():
        g = model.generator(
            torch.from_numpy(fi.point_inputs)[None, :, :, None],
            torch.ones(1, 1, len(ln_law), 1),
            law_z[None, None, :, None],
        )
    z = (g[0, 0, :, 0] + law_z).numpy().astype(np.float64)
    expected = np.maximum(np.exp(z * spec.log_std + spec.log_mean) - spec.floor, 0)
    assert np.allclose(pred.reflectivity, expected, atol=1e-5)
    sharers = ~pred.owner
    assert sharers.sum() > 1000  # sharers are answered at their own inputs, not the owner's
    with pytest.raises(ModelError, match="pointwise"):
        from lads.intensity.predict import predict_image

        predict_image(model, fi)


@pytest.mark.parametrize("variant", ["intensity-kitti", "snow"])
def test_frames_without_a_usable_point_go_through_the_learned_stage(synthetic_tree, variant):
    """A frame whose points all sit at zero range (a blocked sensor), or one without points,
    passes the learned stage: the zero-range points kept, their intensity 0."""
    from lads.config import pipeline_for
    from lads.readers import get_reader
    from lads.worker import stages_for

    reader = get_reader("semantickitti", synthetic_tree("semantickitti"))
    frame = reader.read(reader.items()[0])

    def first(n: int):
        return dataclasses.replace(
            frame,
            points=frame.points[:n].copy(),
            labels=frame.labels[:n],
            outcome=frame.outcome[:n],
        )

    at_origin, none = first(7), first(0)
    at_origin.points[:, :3] = 0.0
    stages = stages_for(pipeline_for("semantickitti", variant))
    for source in (at_origin, none):
        out = source
        for k, stage in enumerate(stages):
            out = stage(out, np.random.default_rng([0, k]))
        origin = ~out.points[:, :3].any(axis=1)
        assert origin.sum() == len(source.points)  # the weather passes them through too
        assert np.all(out.points[origin, 3] == 0.0) and np.isfinite(out.points).all()


def test_a_device_the_machine_lacks_is_a_named_error(tmp_path):
    """`--device cuda` without a CUDA device: a ConfigError saying what to use, before any
    output (not PyTorch's assertion from deep inside the weight loading)."""
    from click.testing import CliRunner

    from lads.cli import main
    from lads.intensity.checkpoint import checked_device
    from lads.synth import write_synthetic_dataset

    assert checked_device("cpu") == "cpu"
    with pytest.raises(ConfigError, match="expected 'cpu' or 'cuda'"):
        checked_device("tpu")
    if torch.cuda.is_available():
        return  # the refusal below needs a machine without CUDA
    with pytest.raises(ConfigError, match="no CUDA device"):
        load_model(tmp_path / "never-read.pt", device="cuda")
    src = tmp_path / "src"
    write_synthetic_dataset(src, sensor="hdl64e", frames=1, layout="semantickitti")
    args = ["build", "--source", "semantickitti", "--variant", "snow", "--device", "cuda"]
    result = CliRunner().invoke(main, [*args, "--in", str(src), "--out", str(tmp_path / "out")])
    assert result.exit_code != 0 and "no CUDA device" in result.output
    assert not (tmp_path / "out").exists()
