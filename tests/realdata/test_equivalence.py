"""The fast weather paths draw from the same distribution as the brute-force references.

Rain and snow: `lads.physics.particles` samples only the particles that can matter
(thinned Poisson process); `tests/reference/particles_bruteforce.py` draws every particle of
every beam cone. On real SemanticKITTI frames both run on the same beams: the fast path with
many seeds, the brute force once per frame. Then, per weather and return mode:

- lost and particle-return fractions: two-proportion z-test p > 0.001 AND Cohen's effect
  size |h| = |2 asin sqrt(p1) - 2 asin sqrt(p2)| <= 0.02 (a "small" effect is 0.2). h has a
  standard error of ~sqrt(1/n_brute) ~ 0.002 here, so the bound never trips by chance,
  yet a 2x change of a 2 % fraction is h ~ 0.12 and of a 0.1 % fraction h ~ 0.026.
  Beams differ in their probabilities, so the pooled-binomial z-test is conservative.
- particle-return range and intensity distributions: two-sample KS test p > 0.001.
- power: the same tests reject a deliberately wrong brute force (rho_p doubled) at p < 0.001.

The frames are run with a fine intensity encoding (step 1e-5 instead of KITTI's 0.01) so
that particle-return intensities (<= rho_p ~ 0.02) are not collapsed onto 2-3 levels;
stored zeros are replaced by the 0.005 KITTI's encoding assumes for them, so the physics
(reflectivities, hence the auto threshold) is that of the real frame.

Fog: `tests/reference/fog_bruteforce.py` integrates each beam's waveform by adaptive
quadrature; peak power agrees with the table within 1 % and outcomes agree beam by beam
outside a 1 % band around ties.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lads.physics.beams import auto_threshold, prepare_beams
from lads.physics.fog import (
    backscatter_from_visibility,
    extinction_from_visibility,
    soft_return_peak,
)
from lads.physics.result import Outcome
from lads.physics.weather import FOG_DEFAULTS, RAIN_DEFAULTS, fog
from lads.sensors.profile import load_profile
from tests.reference import fog_bruteforce as fb
from tests.reference.equivalence import (
    CASES,
    FAST_SEEDS,
    FRAMES,
    LOST,
    MAX_COHEN_H,
    P_VALUE_FLOOR,
    PARTICLE,
    Sample,
    compare,
    fine_frame,
    fine_kitti_profile,
    run_brute,
    run_fast,
)

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def samples(kitti_frame):
    """Fast and brute samples per case, on frames FRAMES (computed once per module)."""
    profile = fine_kitti_profile()
    cache = {}

    def get(case):
        if case not in cache:
            fast, brute = Sample(), Sample()
            drawn = 0
            for i in FRAMES:
                xyz, intensity = fine_frame(*kitti_frame(i))
                for seed in range(FAST_SEEDS):
                    run_fast(xyz, intensity, *case, 1000 * i + seed, fast, profile)
                drawn += run_brute(xyz, intensity, *case, 7 + i, brute, profile)
            cache[case] = (fast, brute, drawn)
        return cache[case]

    return get


@pytest.mark.parametrize("case", CASES, ids=["-".join(map(str, c)) for c in CASES])
def test_fast_path_matches_brute_force_on_real_frames(samples, case):
    fast, brute, drawn = samples(case)
    result = compare(fast, brute)
    print(
        f"\n{case}: {result}; brute {brute.seconds / len(FRAMES):.2f} s/frame "
        f"({drawn / len(FRAMES):.3g} particles/frame), fast "
        f"{1e3 * fast.seconds / (FAST_SEEDS * len(FRAMES)):.1f} ms/frame"
    )
    # Every case must exercise what it tests: returns lost to the weather, and particle
    # returns wherever the detection rule lets drops or flakes through.
    assert brute.lost >= 100, "too few lost returns for the comparison to mean anything"
    tests_particles = case[0] == "snow" or case[3] == "frame"
    assert brute.particle >= 100 or not tests_particles, "too few particle returns"
    for what in ("lost", "particle"):
        stat = result[what]
        assert stat["p"] > P_VALUE_FLOOR, f"{what} fraction differs: {stat}"
        assert abs(stat["h"]) <= MAX_COHEN_H, f"{what} fraction effect size too large: {stat}"
    if tests_particles:
        assert result["range_ks_p"] > P_VALUE_FLOOR, "particle-return ranges differ"
        assert result["intensity_ks_p"] > P_VALUE_FLOOR, "particle-return intensities differ"


def test_comparison_rejects_a_brute_force_with_doubled_particle_reflectivity(samples, kitti_frame):
    """Power: the same statistics tell a wrong model (rho_p x 2) apart at p < 0.001."""
    case = ("rain", 25.0, "strongest", "frame")
    fast, _, _ = samples(case)
    wrong = Sample()
    rho_p = RAIN_DEFAULTS.particle_reflectivity
    for i in FRAMES:
        xyz, intensity = fine_frame(*kitti_frame(i))
        run_brute(
            xyz,
            intensity,
            *case,
            99 + i,
            wrong,
            fine_kitti_profile(),
            particle_reflectivity=2 * rho_p,
        )
    result = compare(fast, wrong)
    print(f"\nrho_p x 2: {result}")
    assert result["particle"]["p"] < P_VALUE_FLOOR
    assert abs(result["particle"]["h"]) > MAX_COHEN_H
    assert result["range_ks_p"] < P_VALUE_FLOOR
    assert result["intensity_ks_p"] < P_VALUE_FLOOR


# --- fog ------------------------------------------------------------------------------------

TIE_BAND = 0.01  # relative distance of two compared powers below which outcomes may differ


@pytest.mark.parametrize("visibility_m", [50.0, 1000.0])
def test_fog_outcomes_match_direct_waveform_integration_beam_by_beam(kitti_frame, visibility_m):
    """simulate_fog (tabulated peak) agrees beam by beam with the integrated waveform."""
    xyz, intensity = kitti_frame(0)
    profile = load_profile("hdl64e")
    params = FOG_DEFAULTS.resolved_for(profile)
    beams = prepare_beams(xyz, intensity, profile)
    # All the table's interpolation happens for r0 < R2 + L (~7 m): sample those densely.
    rng = np.random.default_rng(5)
    near_limit = params.overlap_full_m + params.pulse_length_m + 0.5
    near = np.flatnonzero(beams.range_m < near_limit)
    far = np.flatnonzero(beams.range_m >= near_limit)
    chosen = np.sort(
        np.r_[rng.choice(near, 160, replace=False), rng.choice(far, 60, replace=False)]
    )

    alpha = extinction_from_visibility(visibility_m)
    beta = backscatter_from_visibility(visibility_m, params)
    p_min = auto_threshold(beams)
    constants = fb.FogConstants.from_params(alpha, beta, params)
    r0, rho = beams.range_m[chosen], beams.reflectivity[chosen]
    brute = fb.simulate_beams(r0, rho, constants, p_min, modes=("strongest", "last"))

    table_range, table_power, curvature = soft_return_peak(r0, alpha, beta, params)
    np.testing.assert_allclose(table_power, brute["peak_power"], rtol=0.01)
    np.testing.assert_allclose(table_range, brute["peak_range_m"], atol=0.01)

    def near_tie(a, b):
        return np.abs(a - b) <= TIE_BAND * np.maximum(a, b)

    ties = (
        near_tie(brute["peak_power"], brute["target_power"])
        | near_tie(brute["peak_power"], p_min)
        | near_tie(brute["target_power"], p_min)
    )
    assert (brute["strongest"] == PARTICLE).any() and (brute["strongest"] != PARTICLE).any()
    for mode in ("strongest", "last"):
        # Beam by beam needs a deterministic rule: the frame-calibrated hard threshold.
        result = fog(
            xyz,
            intensity,
            visibility_m=visibility_m,
            sensor=profile,
            mode=mode,
            params=dataclasses.replace(FOG_DEFAULTS, detection_threshold="frame"),
            rng=np.random.default_rng(0),
        )
        fast = np.full(len(xyz), LOST, dtype=np.uint8)
        fast[result.source_index] = result.outcome
        differ = (fast[chosen] != brute[mode]) & ~ties
        assert not differ.any(), (
            f"{mode}: beams {chosen[differ][:5]} (r0 {r0[differ][:5]}) fast "
            f"{fast[chosen][differ][:5]} vs brute {brute[mode][differ][:5]}"
        )
        # Fog returns are reported at the pulse-centre time of the peak, r* - L / 2 (plus
        # millimetres of range noise).
        out_pos = np.searchsorted(result.source_index, chosen)
        is_fog = (fast[chosen] == PARTICLE) & (brute[mode] == PARTICLE)
        fog_range = np.linalg.norm(result.xyz[out_pos[is_fog]].astype(np.float64), axis=1)
        expected = brute["peak_range_m"][is_fog] - 0.5 * params.pulse_length_m
        # The broad echo's peak is timed less precisely than the pulse (fog.py docstring):
        # sigma = dR / sqrt(2 SNR) * kappa_pulse / kappa_fog; allow 5 sigma.
        kappa_pulse = 2.0 * np.pi**2 / params.pulse_length_m**2
        snr = table_power[is_fog] / p_min
        sigma = (
            profile.range_accuracy_m
            / np.sqrt(2.0 * snr)
            * np.minimum(kappa_pulse / np.maximum(curvature[is_fog], 1e-12), 1e6)
        )
        assert np.all(np.abs(fog_range - expected) <= 0.02 + 5.0 * sigma)
    # Dual: the first return of every beam is the strongest's; a second follows where the fog
    # echo is first and the target still detected (the target), or where the target is both
    # strongest and last and the echo is detected (the echo, Velodyne's second strongest).
    dual = fog(
        xyz,
        intensity,
        visibility_m=visibility_m,
        sensor=profile,
        mode="dual",
        params=dataclasses.replace(FOG_DEFAULTS, detection_threshold="frame"),
        rng=np.random.default_rng(0),
    )
    first = np.r_[True, np.diff(dual.source_index) != 0]
    fast = np.full(len(xyz), LOST, dtype=np.uint8)
    fast[dual.source_index[first]] = dual.outcome[first]
    has_second = np.zeros(len(xyz), dtype=bool)
    has_second[dual.source_index[~first]] = True
    echo_seen = brute["peak_power"] >= p_min
    behind = (brute["strongest"] == PARTICLE) & (brute["last"] == Outcome.ATTENUATED)
    apart = brute["peak_range_m"] - 0.5 * params.pulse_length_m <= r0 - params.pulse_length_m
    in_front = (brute["strongest"] == Outcome.ATTENUATED) & echo_seen & apart  # 2nd strongest
    expect_second = behind | in_front
    second_code = np.full(len(xyz), LOST, dtype=np.uint8)
    second_code[dual.source_index[~first]] = dual.outcome[~first]
    want_code = np.where(behind, Outcome.ATTENUATED, PARTICLE)
    assert not ((second_code[chosen] != want_code) & expect_second & ~ties).any()
    assert not ((fast[chosen] != brute["strongest"]) & ~ties).any()
    assert not ((has_second[chosen] != expect_second) & ~ties).any()
    if visibility_m <= 50.0:
        assert expect_second.any()
