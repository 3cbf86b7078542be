"""The concealed-effect benchmark of `lads diagnose`: benchmarks/diagnose_cases/generate.py,
benchmarks/diagnose_cases/score.py and benchmarks/diagnose_bench.py (docs/diagnose.md §6).

Generated cases read the real SemanticKITTI and nuScenes samples from ../shared/data and are
subsampled to a few thousand points per scan so the whole module runs in seconds. Scorer
tests use hand-written truths and fake reports whose right scores are known in advance.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks import diagnose_bench  # noqa: E402
from benchmarks.diagnose_cases import generate as gen  # noqa: E402
from benchmarks.diagnose_cases.score import (  # noqa: E402
    identification,
    log_mse,
    parameter_scores,
    score_case,
    summarise,
)
from lads.readers import get_reader  # noqa: E402

pytestmark = pytest.mark.realdata
SMALL = 3000
KITTI_H = 0.005


@pytest.fixture(scope="module", autouse=True)
def _needs_data():
    for base, root in gen.BASE_ROOTS.items():
        if not root.is_dir():
            pytest.skip(f"{base} sample not found at {root}")


def _files(root: Path) -> dict[str, bytes]:
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _truth(d: Path) -> dict:
    return json.loads((d / "truth.json").read_text())


def _kitti_arrays(root: Path) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    reader = get_reader("semantickitti", root)
    out = []
    for item in reader.items():
        fr = reader.read(item)
        out.append(
            (
                np.asarray(fr.xyz, np.float64),
                np.asarray(fr.intensity, np.float64),
                np.asarray(fr.labels),
            )
        )
    return out


# ----------------------------------------------------------------------------------------
# Generator


def test_same_case_base_seed_mode_gives_identical_bytes(tmp_path):
    for name in ("a", "b"):
        gen.generate_case("K15", "semantickitti", 7, tmp_path / name, mode="M2", max_points=SMALL)
    first, second = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert first.keys() == second.keys()
    assert all(first[k] == second[k] for k in first)
    gen.generate_case("K15", "semantickitti", 8, tmp_path / "c", mode="M2", max_points=SMALL)
    assert (
        _files(tmp_path / "c")["real/sequences/00/velodyne/000000.bin"]
        != (first["real/sequences/00/velodyne/000000.bin"])
    )


def test_kitti_trees_share_relpaths_and_the_reader_reads_both(tmp_path):
    gen.generate_case("K10", "semantickitti", 1, tmp_path, mode="M2", max_points=SMALL)
    sim = get_reader("semantickitti", tmp_path / "sim")
    real = get_reader("semantickitti", tmp_path / "real")
    rel_sim = [it.relpath for it in sim.items()]
    assert rel_sim == [it.relpath for it in real.items()]
    assert rel_sim == [f"sequences/00/velodyne/{i:06d}.bin" for i in range(6)]  # 3 + 3 rotated
    dropped = 0
    for a, b in zip(sim.items(), real.items(), strict=True):
        fa, fb = sim.read(a), real.read(b)
        assert fa.labels is not None and fb.labels is not None  # labels follow the points
        assert len(fa.xyz) == SMALL and len(fb.xyz) <= len(fa.xyz)
        dropped += len(fa.xyz) - len(fb.xyz)
        assert np.all(np.isin(fb.intensity, np.round(np.arange(100) * 0.01, 2).astype(np.float32)))
    assert dropped > 0  # K10 is a dropout case


def test_rotated_kitti_copies_keep_scan_order_rings(tmp_path):
    from lads.sensors.measure import rings_from_scan_order

    gen.generate_case("K18", "semantickitti", 2, tmp_path, mode="M1", max_points=20000)
    truth = _truth(tmp_path)
    yaws = [s["yaw_deg"] for s in truth["scans"]]
    assert yaws[:3] == [0.0, 0.0, 0.0] and all(y != 0.0 for y in yaws[3:])
    for xyz, _, _ in _kitti_arrays(tmp_path / "sim"):
        assert np.unique(rings_from_scan_order(xyz, 64)).size == 64


def test_nuscenes_trees_keep_the_format_and_name(tmp_path):
    gen.generate_case("K2", "nuscenes", 0, tmp_path, mode="M1", max_points=SMALL)
    real_name = next((gen.BASE_ROOTS["nuscenes"] / "samples" / "LIDAR_TOP").glob("*.pcd.bin")).name
    sim = sorted(
        p.relative_to(tmp_path / "sim").as_posix()
        for p in (tmp_path / "sim").rglob("*")
        if p.is_file()
    )
    real = sorted(
        p.relative_to(tmp_path / "real").as_posix()
        for p in (tmp_path / "real").rglob("*")
        if p.is_file()
    )
    assert sim == real and len(sim) == 6
    assert f"samples/LIDAR_TOP/{real_name}" in sim
    for rel in sim:
        pts = np.fromfile(tmp_path / "sim" / rel, dtype="<f4").reshape(-1, 5)
        assert np.linalg.norm(pts[:, :3], axis=1).min() >= gen.MIN_RANGE_M  # ego points gone
        assert np.array_equal(pts[:, 3], np.round(pts[:, 3])) and pts[:, 3].max() <= 255
        assert set(np.unique(pts[:, 4])) <= set(range(32))


def test_class_cases_are_not_available_on_unlabelled_nuscenes(tmp_path):
    assert set(gen.cases_for("semantickitti")) == set(gen.CASES)
    assert set(gen.CASES) - set(gen.cases_for("nuscenes")) == {"K7", "K8", "K11", "K20"}
    for case in ("K7", "K8", "K11", "K20"):
        with pytest.raises(ValueError, match="labels"):
            gen.generate_case(case, "nuscenes", 0, tmp_path)
    with pytest.raises(ValueError):
        gen.generate_case("K21", "semantickitti", 0, tmp_path)


def test_truth_is_written_outside_the_trees_which_hold_no_metadata(tmp_path):
    gen.generate_case("K20", "semantickitti", 0, tmp_path, max_points=SMALL)
    assert (tmp_path / "truth.json").is_file()
    for tree in ("sim", "real", "oracle"):
        suffixes = {p.suffix for p in (tmp_path / tree).rglob("*") if p.is_file()}
        assert suffixes <= {".bin", ".label"}, suffixes
    truth = _truth(tmp_path)
    assert truth["effects"] == [
        {**truth["effects"][0], "id": "C6", "key": "class_reflectance", "classes": ["vegetation"]}
    ]
    assert set(truth["effects"][0]["params"]) == {"ln_scale_vegetation"}
    assert truth["param_ranges"]["ln_scale_vegetation"] == pytest.approx(
        [math.log(0.6), math.log(1.5)]
    )


def test_k2_attenuation_slope_is_minus_two_alpha_without_noise(tmp_path):
    gen.generate_case(
        "K2", "semantickitti", 3, tmp_path, mode="M1", max_points=20000, noise_scale=0.0
    )
    alpha = _truth(tmp_path)["effects"][0]["params"]["alpha_per_m"]
    a = _kitti_arrays(tmp_path / "sim")
    b = _kitti_arrays(tmp_path / "real")
    r = np.concatenate([np.linalg.norm(x, axis=1) for x, _, _ in a])
    ia = np.concatenate([i for _, i, _ in a])
    ib = np.concatenate([i for _, i, _ in b])
    resid = np.log(ib + KITTI_H) - np.log(ia + KITTI_H)
    ok = ib >= 0.05  # quantisation is small against these values
    slope = np.polyfit(r[ok], resid[ok], 1)[0]
    assert slope == pytest.approx(-2.0 * alpha, rel=0.05)
    # Binned means fall with range too.
    bins = [resid[ok & (r >= lo) & (r < hi)].mean() for lo, hi in ((5, 10), (10, 20), (20, 40))]
    assert bins[0] > bins[1] > bins[2]


def test_k18_null_has_zero_mean_log_ratio_in_every_range_bin(tmp_path):
    gen.generate_case("K18", "semantickitti", 1, tmp_path, mode="M1", max_points=20000)
    truth = _truth(tmp_path)
    assert truth["effects"] == [] and truth["noise"]["kind"] == "homoscedastic"
    a, b = _kitti_arrays(tmp_path / "sim"), _kitti_arrays(tmp_path / "real")
    r = np.concatenate([np.linalg.norm(x, axis=1) for x, _, _ in a])
    resid = np.concatenate(
        [
            np.log(ib + KITTI_H) - np.log(ia + KITTI_H)
            for (_, ia, _), (_, ib, _) in zip(a, b, strict=True)
        ]
    )
    assert resid.std() == pytest.approx(truth["noise"]["sigma_ln"], rel=0.25)
    for lo, hi in ((0, 5), (5, 10), (10, 20), (20, 40), (40, 90)):
        sel = (r >= lo) & (r < hi)
        assert abs(resid[sel].mean()) < 0.02, (lo, hi)


def test_effect_size_redraw_keeps_the_hidden_rms_in_band(tmp_path):
    for seed in range(3):
        d = tmp_path / f"s{seed}"
        gen.generate_case("K2", "semantickitti", seed, d, mode="M1", max_points=SMALL)
        truth = _truth(d)
        size = truth["effect_size"]["effects"][0]
        sigma = math.hypot(truth["noise"]["sigma_ln"], truth["noise"]["object_sigma_ln"])
        assert truth["effect_size"]["in_band"]
        assert 0.3 <= size["rms_ln"] / sigma <= 2.0
        # The recorded RMS is the de-meaned -2 alpha R over the written geometry.
        r = np.concatenate([np.linalg.norm(x, axis=1) for x, _, _ in _kitti_arrays(d / "sim")])
        alpha = truth["effects"][0]["params"]["alpha_per_m"]
        assert gen.hidden_rms(-2.0 * alpha * r, None) == pytest.approx(size["rms_ln"], rel=1e-5)
    # A range that cannot meet the band (x5-x50 retro gain) is kept and flagged, not clipped.
    gen.generate_case("K8", "semantickitti", 0, tmp_path / "k8", max_points=SMALL)
    truth = _truth(tmp_path / "k8")
    gain = math.exp(truth["effects"][0]["params"]["ln_gain"])
    assert not truth["effect_size"]["in_band"] and 5.0 <= gain <= 50.0


def test_truth_uses_the_catalogue_parametrisation(tmp_path):
    from lads.diagnose.effects.catalogue import CATALOGUE

    expected = {
        "K1": {"C1"},
        "K3": {"C2"},
        "K5": {"C4"},
        "K9": {"C9"},
        "K10": {"D1"},
        "K11": {"C7"},
        "K12": {"C4", "C5"},
        "K13": {"C1", "C2"},
        "K14": {"C3"},
        "K15": {"C11"},
        "K16": {"C10"},
        "K17": {"C8"},
        "K19": set(),
    }
    for case, ids in expected.items():
        d = tmp_path / case
        gen.generate_case(case, "semantickitti", 0, d, max_points=SMALL)
        truth = _truth(d)
        assert {e["id"] for e in truth["effects"]} == ids, case
        for e in truth["effects"]:
            info = CATALOGUE[e["id"]]
            assert e["key"] == info.key
            assert set(e["params"]) <= set(info.params) | {"drop_fraction"}, (case, e["params"])
            assert set(e["params"]) - {"i_max"} <= set(e["param_ranges"])
        if case == "K5":
            gains = truth["effects"][0]["params"]["ln_gain_by_ring"]
            assert len(gains) == 64 and abs(sum(gains)) < 1e-6
        if case == "K14":
            assert truth["effects"][0]["params"] == {"p_extra": -1.0}
            assert ["C1", "C3"] in truth["accept_ambiguity"]
            classes = np.concatenate([lab & 0xFFFF for _, _, lab in _kitti_arrays(d / "real")])
            assert set(np.unique(classes)) <= set(gen.GROUND_CLASSES)
        if case == "K19":
            assert truth["noise"]["kind"] == "heteroscedastic"


# ----------------------------------------------------------------------------------------
# Scorer

TRUTH_K2 = {
    "case": "K2",
    "base": "semantickitti",
    "mode": "M2",
    "seed": 0,
    "effects": [
        {
            "id": "C5",
            "key": "atmospheric_attenuation",
            "params": {"alpha_per_m": 0.01},
            "param_ranges": {"alpha_per_m": [0.002, 0.03]},
        }
    ],
    "noise": {"kind": "homoscedastic"},
    "accept_ambiguity": [],
    "param_ranges": {"alpha_per_m": [0.002, 0.03]},
}
TRUTH_K14 = {
    **TRUTH_K2,
    "case": "K14",
    "effects": [{"id": "C3", "key": "incidence_law", "params": {"p_extra": -1.0}}],
    "accept_ambiguity": gen.K14_ACCEPT,
    "param_ranges": {"p_extra": [-1.0, 2.0]},
}
TRUTH_K18 = {**TRUTH_K2, "case": "K18", "effects": [], "param_ranges": {}}
TRUTH_K19 = {**TRUTH_K18, "case": "K19", "noise": {"kind": "heteroscedastic"}}


def _effect(id_: str, params: dict, status: str = "claimed", ci: dict | None = None) -> dict:
    return {"id": id_, "key": "k", "params": params, "ci95": ci or {}, "status": status}


def test_identification_exact_wrong_ambiguous_and_k14():
    perfect = {"effects": [_effect("C5", {"alpha_per_m": 0.01}), _effect("C0", {"ln_gain": 0.2})]}
    assert identification(TRUTH_K2, perfect) == 1.0  # C0 is always allowed
    wrong = {"effects": [_effect("C1", {"delta_n": 0.5})]}
    assert identification(TRUTH_K2, wrong) == 0.0
    only_possible = {"effects": [_effect("C5", {"alpha_per_m": 0.01}, status="possible")]}
    assert identification(TRUTH_K2, only_possible) == 0.0
    amb = {
        "verdict": "ambiguous",
        "effects": [_effect("C1", {"delta_n": 0.5})],
        "ambiguity_sets": [{"ids": ["C1", "C5"], "keys": [], "reason": "r"}],
    }
    assert identification(TRUTH_K2, amb) == 0.5
    alt = {
        "effects": [_effect("C1", {"delta_n": 0.5})],
        "alternatives": [{"ids": ["C5"], "instead_of": ["C1"]}],
    }
    assert identification(TRUTH_K2, alt) == 0.5
    k14_set = {"verdict": "ambiguous", "effects": [], "ambiguity_sets": [{"ids": ["C1", "C3"]}]}
    assert identification(TRUTH_K14, k14_set) == 1.0
    assert identification(TRUTH_K14, {"effects": [_effect("C3", {"p_extra": -1.0})]}) == 0.5
    assert identification(TRUTH_K14, {"effects": [_effect("C1", {"delta_n": -1.0})]}) == 0.0
    # An encoding gamma is a function of range on flat ground too; a set reaching beyond the
    # ground confounds (a near-range term) is not accepted.
    gamma = {"effects": [_effect("C9", {"gamma": 0.67})],
             "ambiguity_sets": [{"ids": ["C1", "C3", "C4", "C9"]}]}  # fmt: skip
    assert identification(TRUTH_K14, gamma) == 1.0
    beyond = {"effects": [_effect("C9", {"gamma": 0.67})],
              "ambiguity_sets": [{"ids": ["C2", "C3", "C9"]}]}  # fmt: skip
    assert identification(TRUTH_K14, beyond) == 0.0


K13_EFFECTS = [
    {"id": "C1", "key": "range_exponent", "params": {"delta_n": 0.4}},
    {"id": "C2", "key": "near_range_overlap", "params": {"r0_m": 8.0}},
]
TRUTH_K13 = {**TRUTH_K2, "case": "K13", "effects": K13_EFFECTS}


def test_a_pair_earns_half_credit_only_when_the_ambiguity_swaps_the_wrong_effect_for_the_true():
    c2 = _effect("C2", {"r0_m": 8.0})
    c5 = _effect("C5", {"alpha_per_m": 0.01})

    def claim(*sets: list[str]) -> dict:
        return {"effects": [c2, c5], "ambiguity_sets": [{"ids": s} for s in sets]}

    assert identification(TRUTH_K13, claim(["C1", "C5"])) == 0.5  # {C2, C1} is left open
    assert identification(TRUTH_K13, claim(["C1", "C2"])) == 0.0  # C5 is claimed firmly
    assert identification(TRUTH_K13, claim(["C5", "C9"])) == 0.0  # C1 is never offered
    assert identification(TRUTH_K13, claim()) == 0.0
    assert identification(TRUTH_K13, {"effects": [c2, _effect("C1", {"delta_n": 0.4})]}) == 1.0
    # A truth two swaps away, through two sets, earns nothing: the rule asks for one set.
    c9 = _effect("C9", {"gamma": 1.2})
    two = {"effects": [c9, c5], "ambiguity_sets": [{"ids": ["C1", "C5"]}, {"ids": ["C2", "C9"]}]}
    assert identification(TRUTH_K13, two) == 0.0


def test_false_discovery_on_the_null_cases(tmp_path):
    gen.generate_case("K18", "semantickitti", 0, tmp_path, max_points=SMALL)
    dirs = {
        "sim_dir": tmp_path / "sim",
        "real_dir": tmp_path / "real",
        "oracle_dir": tmp_path / "oracle",
        "corrected_dir": None,
    }
    truth = _truth(tmp_path)
    claim = score_case(truth, {"effects": [_effect("C5", {"alpha_per_m": 0.01})]}, **dirs)
    assert claim["false_discovery"] is True and claim["identification"] == 0.0
    gain = score_case(
        truth,
        {"verdict": "no_missing_physics", "effects": [_effect("C0", {"ln_gain": 0.1})]},
        **dirs,
    )
    assert gain["false_discovery"] is False and gain["identification"] == 1.0
    assert claim["recovery_ratio"] is None  # no corrected tree, and nothing to recover
    hetero = score_case(
        {**truth, "case": "K19", "noise": {"kind": "heteroscedastic"}},
        {"effects": [], "noise_model": {"kind": "heteroscedastic"}},
        **dirs,
    )
    assert hetero["noise_kind_ok"] is True and hetero["false_discovery"] is False


def test_parameter_error_and_coverage_on_a_fake_report():
    width = 0.03 - 0.002
    est = 0.01 + 0.1 * width
    report = {
        "effects": [
            _effect("C5", {"alpha_per_m": est}, ci={"alpha_per_m": [est - 0.001, est + 0.001]})
        ]
    }
    (row,) = parameter_scores(TRUTH_K2, report)
    assert row["error"] == pytest.approx(0.1) and row["covered"] is False
    report["effects"][0]["ci95"] = {"alpha_per_m": [0.009, est + 0.001]}
    assert parameter_scores(TRUTH_K2, report)[0]["covered"] is True
    # Per-ring lists: compared elementwise, up to a common offset (a global gain).
    truth_c4 = {
        "effects": [
            {
                "id": "C4",
                "params": {"ln_gain_by_ring": [0.2, -0.1, -0.1, 0.0]},
                "param_ranges": {"ln_gain_by_ring": [-0.6, 0.6]},
            }
        ]
    }
    shifted = {"effects": [_effect("C4", {"ln_gain_by_ring": [0.5, 0.2, 0.2, 0.3]})]}
    assert parameter_scores(truth_c4, shifted)[0]["error"] == pytest.approx(0.0, abs=1e-12)
    off = {"effects": [_effect("C4", {"ln_gain_by_ring": [0.32, -0.1, -0.1, 0.0]})]}
    assert parameter_scores(truth_c4, off)[0]["error"] == pytest.approx(0.0, abs=1e-12)  # median
    sparse = {"effects": [{**truth_c4["effects"][0], "rings": [0]}]}
    assert parameter_scores(sparse, off)[0]["error"] == pytest.approx(0.12 / 1.2)
    # Azimuth on the circle.
    truth_c11 = {
        "effects": [
            {
                "id": "C11",
                "params": {"start_deg": 359.0},
                "param_ranges": {"start_deg": [0.0, 360.0]},
            }
        ]
    }
    rep = {"effects": [_effect("C11", {"start_deg": 1.0}, ci={"start_deg": [-2.0, 3.0]})]}
    (row,) = parameter_scores(truth_c11, rep)
    assert row["error"] == pytest.approx(2.0 / 360.0) and row["covered"] is True
    # Class scales are relative to the other classes' scales.
    truth_c6 = {
        "effects": [
            {
                "id": "C6",
                "params": {"ln_scale_vegetation": -0.3},
                "param_ranges": {"ln_scale_vegetation": [-0.51, 0.41]},
            }
        ]
    }
    rep = {
        "effects": [
            _effect(
                "C6", {"ln_scale_vegetation": -0.2, "ln_scale_road": 0.1, "ln_scale_building": 0.1}
            )
        ]
    }
    assert parameter_scores(truth_c6, rep)[0]["error"] == pytest.approx(0.0, abs=1e-12)
    # Unidentifiable parameters are skipped.
    truth_sat = {
        "effects": [
            {
                "id": "C3r",
                "params": {"ln_gain": 3.0},
                "param_ranges": {"ln_gain": [1.6, 3.9]},
                "unidentifiable_params": ["ln_gain"],
            }
        ]
    }
    assert parameter_scores(truth_sat, {"effects": [_effect("C3r", {"ln_gain": 1.0})]}) == []


def test_perfect_report_with_the_oracle_as_correction_scores_full_marks(tmp_path):
    gen.generate_case("K2", "semantickitti", 4, tmp_path, mode="M1", max_points=SMALL)
    truth = _truth(tmp_path)
    eff = truth["effects"][0]
    alpha = eff["params"]["alpha_per_m"]
    report = {
        "verdict": "effects_found",
        "effects": [
            _effect("C5", {"alpha_per_m": alpha}, ci={"alpha_per_m": [alpha * 0.9, alpha * 1.1]})
        ],
        "noise_model": {"kind": "homoscedastic"},
    }
    score = score_case(
        truth,
        report,
        sim_dir=tmp_path / "sim",
        real_dir=tmp_path / "real",
        corrected_dir=tmp_path / "oracle",
        oracle_dir=tmp_path / "oracle",
    )
    assert score["identification"] == 1.0 and score["precision"] == score["recall"] == 1.0
    assert score["median_parameter_error"] == pytest.approx(0.0, abs=1e-9)
    assert score["parameters"][0]["covered"] is True
    assert score["recovery_ratio"] == pytest.approx(1.0)
    assert score["L_before"] > score["L_oracle"]
    # An uncorrected "correction" recovers nothing.
    none = score_case(
        truth,
        report,
        sim_dir=tmp_path / "sim",
        real_dir=tmp_path / "real",
        corrected_dir=tmp_path / "sim",
        oracle_dir=tmp_path / "oracle",
    )
    assert none["recovery_ratio"] == pytest.approx(0.0)


def test_log_mse_matches_dropped_rows_by_nearest_neighbour(tmp_path):
    gen.generate_case("K10", "semantickitti", 0, tmp_path, mode="M1", max_points=SMALL)
    truth = _truth(tmp_path)
    assert truth["drop_fraction"] > 0.0
    # K10 leaves intensities unchanged: oracle == sim, and B differs from both by noise only.
    l_sim = log_mse(tmp_path / "sim", tmp_path / "real", KITTI_H)
    l_oracle = log_mse(tmp_path / "oracle", tmp_path / "real", KITTI_H)
    assert l_sim == pytest.approx(l_oracle)
    assert l_sim == pytest.approx(truth["noise"]["sigma_ln"] ** 2, rel=0.3)


def test_summarise_computes_rates_and_targets():
    def s(case, group, ident, fd=None, params=(), rec=None, noise_ok=False, tp=1, fp=0, fn=0):
        return {
            "case": case,
            "group": group,
            "identification": ident,
            "false_discovery": fd,
            "parameters": list(params),
            "recovery_ratio": rec,
            "noise_kind_ok": noise_ok,
            "tp": tp,
            "fp": fp,
            "fn": fn,
            "error": None,
        }

    scores = [
        s("K1", "single", 1.0, params=[{"error": 0.02, "covered": True}], rec=0.95),
        s("K2", "single", 0.5, params=[{"error": 0.2, "covered": False}], rec=0.8, fp=1),
        s("K12", "pairs", 1.0, params=[{"error": 0.05, "covered_fraction": 1.0}], rec=1.0),
        s("K18", "null", 1.0, fd=False, tp=0),
        s("K19", "null", 0.0, fd=True, noise_ok=True, tp=0, fp=1),
    ]
    out = summarise(scores)
    assert out["identification_single"] == pytest.approx(0.75)
    assert out["identification_pairs"] == pytest.approx(1.0)
    assert out["null_false_discovery_rate"] == pytest.approx(0.5)
    assert out["k19_noise_model_rate"] == pytest.approx(1.0)
    assert out["median_parameter_error"] == pytest.approx(0.05)
    assert out["ci_coverage"] == pytest.approx(2.0 / 3.0)
    assert out["median_recovery_ratio"] == pytest.approx(0.95)
    assert out["precision"] == pytest.approx(3.0 / 4.0)
    t = out["targets"]
    assert t["identification_single"]["met"] is False and t["identification_pairs"]["met"] is True
    assert t["null_false_discovery_rate"]["met"] is False
    assert t["median_parameter_error"]["met"] is True and t["ci_coverage"]["met"] is False
    assert t["median_recovery_ratio"]["met"] is True
    assert out["per_case"]["K2"]["identification"] == 0.5


# ----------------------------------------------------------------------------------------
# Bench driver


def test_ci_plan_covers_every_case_once_plus_nuscenes():
    runs = diagnose_bench.plan(diagnose_bench.parse(["--subset", "ci"]))
    kitti = [r for r in runs if r[1] == "semantickitti"]
    assert sorted(r[0] for r in kitti) == sorted(gen.CASES)
    assert {r[0] for r in runs if r[1] == "nuscenes"} == set(diagnose_bench.CI_NUSCENES)
    assert len(runs) == 23 and {r[3] for r in runs} == {"M2"}
    full = diagnose_bench.plan(diagnose_bench.parse(["--full"]))
    assert len(full) == 20 * (20 + 16)
    cmd = diagnose_bench.tool_command(Path("A"), Path("B"), "nuscenes", Path("O"), 3, Path("C"))
    assert cmd[:4] == [sys.executable, "-m", "lads.cli", "diagnose"] and "--paired" in cmd
    one_core = diagnose_bench.tool_command(Path("A"), Path("B"), "nuscenes", Path("O"), 3,
                                           Path("C"), jobs=1)  # fmt: skip
    assert one_core[one_core.index("--jobs") + 1] == "1"


def test_bench_runs_a_tool_subprocess_and_scores_its_report(tmp_path, monkeypatch):
    fake_tool = (
        "import json, shutil, sys, pathlib\n"
        "sim, out, corr = map(pathlib.Path, sys.argv[1:4])\n"
        "out.mkdir(parents=True)\n"
        "(out / 'report.json').write_text(json.dumps({'verdict': 'no_missing_physics',"
        " 'effects': [], 'noise_model': {'kind': 'homoscedastic'}}))\n"
        "shutil.copytree(sim, corr)\n"
    )

    def command(sim, real, base, out, seed, corr, jobs):
        return [sys.executable, "-c", fake_tool, str(sim), str(out), str(corr)]

    monkeypatch.setattr(diagnose_bench, "tool_command", command)
    score = diagnose_bench.run_one(
        "K18", "semantickitti", 0, "M2", tmp_path, max_points=SMALL, timeout=60
    )
    assert score["error"] is None and score["identification"] == 1.0
    assert score["false_discovery"] is False
    payload = {"subset": "test", "summary": summarise([score]), "runs": [score]}
    text = diagnose_bench.markdown(payload)
    assert "| K18 |" in text and "null_false_discovery_rate" in text


def test_ground_truth_incidence_is_the_ground_planes_and_other_points_keep_theirs():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-40.0, 40.0, (4000, 2))
    xyz = np.column_stack([xy, np.full(len(xy), -1.73)])
    noisy = np.clip(rng.uniform(0.0, 1.0, len(xy)), 0.05, 1.0)  # image normals, far off
    ground = np.arange(len(xy)) < 3000
    cos = gen.ground_plane_cos(xyz, ground, noisy)
    exact = 1.73 / np.linalg.norm(xyz, axis=1)
    assert np.allclose(cos[ground], exact[ground], atol=1e-6)
    assert np.array_equal(cos[~ground], noisy[~ground])
