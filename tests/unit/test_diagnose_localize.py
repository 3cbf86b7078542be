"""Localizing the sim-to-real mismatch: lads/diagnose/{localize,binning,binstats}.py, figures.py.

The beam tables are synthetic: 500 spatial groups (10 scans x 50 tiles) of 100 beams, each
tile at its own distance, half of them ground. The residual r = ln(I_real + h) - ln(I_sim + h)
is set exactly by choosing I_real, so the right answer is known: a hidden -2 alpha R term,
pure noise, or noise plus a per-group random effect (object reflectance spread).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lads.diagnose.data.table import BeamTable, SensorInfo
from lads.diagnose.output import figures
from lads.diagnose.where.binning import FEATURES
from lads.diagnose.where.localize import Residuals, localize, residuals, to_json
from lads.errors import InputDataError

HDL64E_UNIT = SensorInfo(
    profile="hdl64e",
    n_rings=64,
    encoding_kind="unit",
    step=0.01,
    max_value=0.99,
    full_scale=1.0,
    calibrated=False,
    has_ring_column=False,
    label_set="semantickitti",
)
GROUND_CLASSES = (40, 48, 72)  # road, sidewalk, terrain
OBJECT_CLASSES = (10, 50, 70, 80)  # car, building, vegetation, pole
CLASS_NAMES = {
    10: "car",
    40: "road",
    48: "sidewalk",
    50: "building",
    70: "vegetation",
    72: "terrain",
    80: "pole",
}
SENSOR_HEIGHT_M = 1.73
ALPHA_PER_M = 0.005
NOISE = 0.3
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def make_table(
    seed: int,
    *,
    alpha: float = 0.0,
    group_sd: float = 0.0,
    noise: float = NOISE,
    drop=lambda range_m: np.full(range_m.shape, 0.05),
    n_scans: int = 10,
    groups_per_scan: int = 50,
    rows_per_group: int = 100,
    labelled: bool = True,
) -> BeamTable:
    """A beam table with r = -2 alpha R + u_group + noise and P(drop) = drop(R).

    Every field of BeamTable is filled; 2% of the rows are real-only returns.
    """
    rng = np.random.default_rng(seed)
    n_groups = n_scans * groups_per_scan
    g = np.repeat(np.arange(n_groups), rows_per_group)
    n = g.size
    centre_m = np.exp(rng.uniform(np.log(1.5), np.log(110.0), n_groups))[g]
    ground = (rng.random(n_groups) < 0.5)[g]
    classes = np.where(
        ground, rng.choice(GROUND_CLASSES, n_groups)[g], rng.choice(OBJECT_CLASSES, n_groups)[g]
    )
    range_m = np.clip(centre_m * np.exp(rng.normal(0.0, 0.1, n)), 1.0, 130.0)
    azimuth = np.mod(rng.uniform(0, 360, n_groups)[g] + rng.normal(0, 2.0, n), 360.0)
    cos = np.where(ground, np.minimum(SENSOR_HEIGHT_M / range_m, 1.0), rng.uniform(0.05, 1, n))
    elevation = np.where(
        ground,
        -np.degrees(np.arcsin(np.minimum(SENSOR_HEIGHT_M / range_m, 1))),
        rng.uniform(-24.8, 2.0, n),
    )
    i_sim = np.round(rng.uniform(0.02, 0.9, n), 2)
    r = -2.0 * alpha * range_m + rng.normal(0, group_sd, n_groups)[g] + rng.normal(0, noise, n)
    h = HDL64E_UNIT.half_step
    ret_sim = rng.random(n) >= 0.02
    ret_real = ~ret_sim | (rng.random(n) >= drop(range_m))
    i_real = np.where(ret_real, (i_sim + h) * np.exp(r) - h, np.nan)
    i_real = np.where(ret_sim, i_real, np.round(rng.uniform(0.02, 0.9, n), 2))
    i_sim = np.where(ret_sim, i_sim, np.nan)
    f32 = np.float32
    return BeamTable(
        sensor=HDL64E_UNIT,
        scans=tuple(f"sequences/00/velodyne/{i:06d}.bin" for i in range(n_scans)),
        class_names=CLASS_NAMES if labelled else {},
        scan=(g // groups_per_scan).astype(np.int32),
        group=(g * 7919 + 12345).astype(np.int64),  # arbitrary ids, unique per group
        ring=rng.integers(0, 64, n).astype(np.int16),
        azimuth_deg=azimuth.astype(f32),
        elevation_deg=elevation.astype(f32),
        range_m=range_m.astype(f32),
        cos_incidence=cos.astype(f32),
        normal_ok=rng.random(n) < 0.9,
        class_id=(classes if labelled else np.full(n, -1)).astype(np.int32),
        is_ground=ground,
        height_m=np.where(ground, 0.0, rng.uniform(0, 3, n)).astype(f32),
        edge_beams=np.minimum(rng.geometric(0.3, n) - 1, 10).astype(f32),
        edge_span_beams=np.zeros(n, f32),
        i_sim=i_sim.astype(f32),
        i_real=i_real.astype(f32),
        ret_sim=ret_sim,
        ret_real=ret_real,
        sim_index=np.where(ret_sim, np.arange(n), -1).astype(np.int64),
        real_index=np.where(ret_real, np.arange(n), -1).astype(np.int64),
    )


def long_range_dropout(range_m: np.ndarray) -> np.ndarray:
    return np.where(range_m > 60.0, 0.3, 0.02)


@pytest.fixture(scope="module")
def attenuated():
    table = make_table(1, alpha=ALPHA_PER_M, group_sd=0.2)
    return table, localize(table, rng=np.random.default_rng(0))


def test_residuals_are_log_ratios_on_beams_both_returned():
    table = make_table(2, groups_per_scan=5)
    res = residuals(table)
    assert isinstance(res, Residuals)
    both = table.ret_sim & table.ret_real
    h = table.sensor.half_step
    expected = np.log(table.i_real[both] + h) - np.log(table.i_sim[both] + h)
    np.testing.assert_allclose(res.r[both], expected, rtol=1e-5, atol=1e-6)
    assert np.isnan(res.r[~both]).all()
    np.testing.assert_array_equal(res.d_drop, table.ret_sim & ~table.ret_real)
    np.testing.assert_array_equal(res.d_extra, table.ret_real & ~table.ret_sim)


def test_the_features_of_discovery_5_2_are_binned(attenuated):
    table, loc = attenuated
    assert [f.name for f in FEATURES] == [
        "range",
        "cos_incidence",
        "class",
        "ring",
        "azimuth",
        "i_sim_decile",
        "edge_distance",
        "ground",
        "scan",
    ]
    assert list(loc.features) == [f.name for f in FEATURES]
    rng_profile = loc.features["range"]
    assert rng_profile.labels == (
        "0.9-2 m",
        "2-5 m",
        "5-10 m",
        "10-20 m",
        "20-40 m",
        "40-80 m",
        "80-120 m",
    )
    # Every returned beam is in a range bin: beyond 120 m (up to 130 m here) is the last bin.
    assert rng_profile.counts.sum() == np.isfinite(residuals(table).r).sum()
    assert len(loc.features["cos_incidence"].labels) == 10
    assert len(loc.features["azimuth"].labels) == 36
    assert len(loc.features["i_sim_decile"].labels) == 10
    assert loc.features["edge_distance"].labels[-1] == "10+ beams"
    assert loc.features["ground"].labels == ("non-ground", "ground")
    assert set(loc.features["class"].labels) == set(CLASS_NAMES.values())
    # cos(theta) uses only rows with a well-conditioned normal.
    r = residuals(table).r
    assert loc.features["cos_incidence"].counts.sum() == np.sum(np.isfinite(r) & table.normal_ok)


def test_range_attenuation_is_significant_decreasing_and_ranked_first(attenuated):
    _, loc = attenuated
    profile = loc.features["range"].intensity
    assert profile.q_value < 1e-6
    assert profile.direction == "decreases"
    # -2 alpha R: slope -0.01 per m (the group effect and noise add scatter).
    assert profile.slope == pytest.approx(-2 * ALPHA_PER_M, abs=3 * profile.slope_se)
    first = loc.statements[0]
    assert (first["feature"], first["target"], first["direction"]) == (
        "range",
        "intensity",
        "decreases",
    )
    assert "decreases" in first["text"] and "per m" in first["text"]
    assert "ground and non-ground agree" in first["text"]
    # Far bins are lower: the extremes run from a near bin to the far bin.
    assert first["bins"][1] == "80-120 m"
    assert first["effect_size"] == pytest.approx(profile.effect_size)
    ranked = [s["effect_size"] for s in loc.statements if s["target"] == "intensity"]
    assert ranked == sorted(ranked, reverse=True)
    assert all(s["q_value"] < 0.05 for s in loc.statements)


def test_every_bin_has_ordered_confidence_intervals(attenuated):
    _, loc = attenuated
    s = loc.features["range"].intensity
    assert np.all(s.mean_low <= s.mean) and np.all(s.mean <= s.mean_high)
    assert np.all(s.median_low <= s.median) and np.all(s.median <= s.median_high)
    d = loc.features["range"].dropout
    assert np.all((d.mean_low <= d.mean) & (d.mean <= d.mean_high))
    assert np.all((d.mean >= 0) & (d.mean <= 1))


def test_trend_slope_and_se_match_statsmodels_cluster_robust_ols():
    sm = pytest.importorskip("statsmodels.api")
    table = make_table(3, alpha=ALPHA_PER_M, group_sd=0.2, groups_per_scan=10)
    loc = localize(table, rng=np.random.default_rng(0), n_boot=20)
    r = residuals(table).r
    ok = np.isfinite(r)
    x = np.clip(table.range_m[ok].astype(np.float64), 0.9, 120.0)
    fit = sm.OLS(r[ok], sm.add_constant(x)).fit(
        cov_type="cluster", cov_kwds={"groups": table.group[ok]}
    )
    s = loc.features["range"].intensity
    assert s.slope == pytest.approx(fit.params[1], rel=1e-9)
    assert s.slope_se == pytest.approx(fit.bse[1], rel=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_pure_noise_gives_no_statement(seed):
    # Noise plus a per-group random effect (object reflectance spread), constant 5% dropout.
    table = make_table(100 + seed, group_sd=0.2)
    loc = localize(table, rng=np.random.default_rng(seed), n_boot=50)
    assert loc.statements == []
    qs = [getattr(p, t).q_value for p in loc.features.values() for t in ("intensity", "dropout")]
    assert min(q for q in qs if math.isfinite(q)) > 0.05


def test_a_weak_ring_is_a_categorical_ring_statement():
    table = make_table(11, group_sd=0.2)
    gain = np.zeros(64)
    gain[12] = -0.5
    r = residuals(table).r + gain[table.ring]
    loc = localize(table, r, rng=np.random.default_rng(0), n_boot=50)
    first = loc.statements[0]
    assert (first["feature"], first["direction"]) == ("ring", "varies")
    assert first["bins"][0] == "ring 12" and "lowest ring 12" in first["text"]
    assert first["effect_size"] == pytest.approx(0.5, abs=0.15)


def test_long_range_dropout_is_a_range_dropout_statement():
    table = make_table(4, group_sd=0.2, drop=long_range_dropout)
    loc = localize(table, rng=np.random.default_rng(0), n_boot=100)
    drops = [s for s in loc.statements if s["target"] == "dropout"]
    assert drops and drops[0]["feature"] == "range"
    assert drops[0]["direction"] == "increases"
    assert "dropout rate increases" in drops[0]["text"]
    rate = loc.features["range"].drop_rate
    assert rate[-1] == pytest.approx(0.3, abs=0.05) and rate[1] == pytest.approx(0.02, abs=0.02)
    # The intensity residual carries no range effect.
    assert loc.features["range"].intensity.q_value > 0.05


def test_a_missing_lambert_term_makes_ground_and_non_ground_disagree_on_range():
    # r = ln cos(theta): on the ground cos = h/R, so r falls with range there only.
    table = make_table(5)
    r = np.log(np.clip(table.cos_incidence, 0.02, 1.0)) + np.random.default_rng(1).normal(
        0, NOISE, len(table)
    )
    r = np.where(table.ret_sim & table.ret_real, r, np.nan)
    loc = localize(table, r, rng=np.random.default_rng(0), n_boot=100)
    statement = next(s for s in loc.statements if s["feature"] == "range")
    assert "ground and non-ground disagree" in statement["text"]
    assert loc.features["range"].intensity.agreement["agree"] is False


def test_cluster_bootstrap_ci_is_wider_with_a_group_random_effect():
    def mean_width(group_sd: float) -> float:
        table = make_table(6, group_sd=group_sd)
        s = localize(table, rng=np.random.default_rng(0), n_boot=100).features["range"].intensity
        return float(np.mean(s.mean_high - s.mean_low))

    independent, clustered = mean_width(0.0), mean_width(0.3)
    assert clustered > 2.0 * independent


def test_a_residual_after_the_fit_is_localized_instead():
    table = make_table(8, alpha=ALPHA_PER_M)
    before = localize(table, rng=np.random.default_rng(0), n_boot=50)
    after_r = residuals(table).r + 2 * ALPHA_PER_M * table.range_m  # the fitted term removed
    after = localize(table, after_r, rng=np.random.default_rng(0), n_boot=50)
    assert before.features["range"].intensity.q_value < 1e-6
    assert after.features["range"].intensity.q_value > 0.05
    assert (
        after.features["range"].intensity.effect_size
        < 0.1 * before.features["range"].intensity.effect_size
    )
    assert after.residual_given and not before.residual_given
    with pytest.raises(InputDataError, match="one value per row"):
        localize(table, after_r[:-1], rng=np.random.default_rng(0))


def test_unlabelled_tables_have_no_class_feature():
    table = make_table(10, groups_per_scan=10, labelled=False)
    loc = localize(table, rng=np.random.default_rng(0), n_boot=20)
    assert "class" not in loc.features
    assert set(loc.heatmaps) == {"range_x_cos", "ring_x_range"}


def test_heatmaps_hold_mean_residual_and_blank_sparse_cells(attenuated):
    table, loc = attenuated
    assert set(loc.heatmaps) == {"range_x_cos", "ring_x_range", "class_x_range"}
    hm = loc.heatmaps["range_x_cos"]
    assert hm.mean.shape == (7, 10) and hm.count.shape == (7, 10)
    assert np.all(np.isnan(hm.mean[hm.count < 20]))
    assert np.all(np.isfinite(hm.mean[hm.count >= 20]))
    rows = loc.heatmaps["ring_x_range"]
    assert rows.mean.shape == (64, 7)
    # Far columns are darker (attenuation) in every well-filled ring.
    assert np.nanmean(rows.mean[:, -1]) < np.nanmean(rows.mean[:, 2]) - 0.5


def test_json_output_is_strict_json(attenuated):
    _, loc = attenuated
    doc = to_json(loc)
    text = json.dumps(doc, allow_nan=False)
    back = json.loads(text)
    assert back["statements"][0]["feature"] == "range"
    assert back["features"]["range"]["intensity"]["q_value"] < 1e-6
    assert back["features"]["range"]["dropout"]["median"] == [None] * 7


def test_figures_write_png_files(attenuated, tmp_path):
    table, loc = attenuated
    after = localize(
        table,
        residuals(table).r + 2 * ALPHA_PER_M * table.range_m,
        rng=np.random.default_rng(0),
        n_boot=20,
    )
    rng = np.random.default_rng(0)
    gains = rng.normal(0, 0.1, 64)
    steps = [
        {
            "step": 1,
            "candidate": "C5",
            "delta_loss": 0.12,
            "se": 0.01,
            "delta_bic": -300,
            "accepted": True,
        },
        {
            "step": 1,
            "candidate": "C1",
            "delta_loss": 0.09,
            "se": 0.01,
            "delta_bic": -200,
            "accepted": False,
        },
        {
            "step": 2,
            "candidate": "C4",
            "delta_loss": 0.001,
            "se": 0.002,
            "delta_bic": 40,
            "accepted": False,
        },
    ]
    p_return = np.where(table.range_m > 60, 0.7, 0.98)
    written = [
        figures.residual_panels(loc, after, tmp_path / "residuals.png"),
        figures.residual_panels(loc, None, tmp_path / "residuals_before.png"),
        figures.heatmaps(loc, tmp_path / "heatmaps.png"),
        figures.ring_gains(gains, gains - 0.05, gains + 0.05, tmp_path / "rings.png"),
        figures.return_rate(table, p_return, tmp_path / "return_rate.png"),
        figures.return_rate(
            make_table(9, groups_per_scan=5, labelled=False),
            None,
            tmp_path / "return_rate_unlabelled.png",
        ),
        figures.bootstrap_histograms(
            {
                "alpha_per_m": rng.normal(0.005, 0.0005, 200),
                "ln_gain_by_ring": rng.normal(0, 0.1, (200, 3)),
            },
            tmp_path / "bootstrap.png",
        ),
        figures.selection_trace(steps, tmp_path / "selection.png"),
        figures.point_noise(
            {
                "kind": "heteroscedastic",
                "range_slope": 0.8,
                "by_range": [
                    {"range_m": r, "sigma_ln_i": 0.01 * r**0.8, "fitted_sigma_ln_i": 0.011 * r**0.8}
                    for r in (3.0, 7.0, 15.0)
                ]
                # rounding as large as the differences: no model-free point
                + [{"range_m": 30.0, "sigma_ln_i": None, "fitted_sigma_ln_i": 0.17}],
            },
            tmp_path / "point_noise.png",
        ),
        figures.point_noise({"kind": "undetermined"}, tmp_path / "point_noise_empty.png"),
    ]
    for path in written:
        assert path.parent == tmp_path
        data = path.read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 5000
    assert not list(tmp_path.glob("*.lads-tmp"))
