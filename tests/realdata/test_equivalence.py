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
import math
import time

import numpy as np
import pytest
from scipy import stats

from lads.physics.beams import auto_threshold, prepare_beams
from lads.physics.fog import (
    FogParams,
    backscatter_from_visibility,
    extinction_from_visibility,
    soft_return_peak,
)
from lads.physics.particles import resolve_optics
from lads.physics.result import Outcome
from lads.physics.weather import RAIN_DEFAULTS, SNOW_DEFAULTS, fog, rain, snow
from lads.sensors.profile import IntensityEncoding, load_profile
from tests.reference import fog_bruteforce as fb
from tests.reference import particles_bruteforce as bf

pytestmark = pytest.mark.realdata

FRAMES = (0, 1)
FAST_SEEDS = 24
P_VALUE_FLOOR = 1e-3
MAX_COHEN_H = 0.02
WEATHER = {"rain": (rain, RAIN_DEFAULTS), "snow": (snow, SNOW_DEFAULTS)}
CASES = [
    ("rain", 25.0, "strongest"),
    ("rain", 25.0, "last"),
    ("snow", 10.0, "strongest"),
    ("snow", 10.0, "last"),
]
LOST, PARTICLE = int(Outcome.LOST), int(Outcome.PARTICLE)
FINE_STEP = 1e-5


def fine_kitti_profile():
    kitti = load_profile("hdl64e")
    return dataclasses.replace(kitti, intensity=IntensityEncoding("unit", 1.0, FINE_STEP, 0.99))


def on_fine_grid(reflectivity: np.ndarray) -> np.ndarray:
    """The brute force's own encoding onto the fine grid (round to the step, clip)."""
    return np.clip(np.rint(reflectivity / FINE_STEP), 0, round(0.99 / FINE_STEP)) * FINE_STEP


@dataclasses.dataclass
class Sample:
    """Outcomes of one implementation, pooled over runs (and frames)."""

    beams: int = 0
    lost: int = 0
    particle: int = 0
    ranges: list = dataclasses.field(default_factory=list)
    intensities: list = dataclasses.field(default_factory=list)
    seconds: float = 0.0

    def add(self, outcome, ranges, intensities):
        self.beams += outcome.size
        self.lost += int((outcome == LOST).sum())
        self.particle += int((outcome == PARTICLE).sum())
        self.ranges.append(np.asarray(ranges, dtype=np.float64))
        self.intensities.append(np.asarray(intensities, dtype=np.float64))

    @property
    def range_m(self):
        return np.concatenate(self.ranges)

    @property
    def intensity(self):
        return np.concatenate(self.intensities)


def fine_frame(kitti_frame, i):
    xyz, intensity = kitti_frame(i)
    floor = load_profile("hdl64e").intensity.detection_floor
    return xyz, np.where(intensity == 0, np.float32(floor), intensity)


def run_fast(xyz, intensity, weather, rate, mode, seed, sample, profile):
    simulate, params = WEATHER[weather]
    t = time.perf_counter()
    result = simulate(
        xyz, intensity, rate_mm_h=rate, sensor=profile, mode=mode, params=params,
        rng=np.random.default_rng(seed),
    )  # fmt: skip
    sample.seconds += time.perf_counter() - t
    outcome = np.full(len(xyz), LOST, dtype=np.uint8)
    outcome[result.source_index] = result.outcome
    is_particle = result.outcome == PARTICLE
    sample.add(
        outcome,
        np.linalg.norm(result.xyz[is_particle].astype(np.float64), axis=1),
        result.intensity[is_particle],
    )


def run_brute(xyz, intensity, weather, rate, mode, seed, sample, profile, **wrong):
    beams = prepare_beams(xyz, intensity, profile)
    constants = bf.Constants.from_optics(resolve_optics(beams, profile, rate, WEATHER[weather][1]))
    constants = dataclasses.replace(constants, **wrong)
    rho_out = profile.intensity.to_reflectivity(beams.intensity)
    t = time.perf_counter()
    res = bf.simulate(beams, rho_out, constants, mode, np.random.default_rng(seed))
    sample.seconds += time.perf_counter() - t
    is_particle = res.outcome == PARTICLE
    sample.add(res.outcome, res.range_m[is_particle], on_fine_grid(res.reflectivity[is_particle]))
    return res.particles_drawn


def two_proportion(k1, n1, k2, n2):
    """(two-sided p-value of the pooled z-test, Cohen's h) for k1/n1 vs k2/n2."""
    p1, p2, pooled = k1 / n1, k2 / n2, (k1 + k2) / (n1 + n2)
    se = math.sqrt(pooled * (1 - pooled) * (1 / n1 + 1 / n2))
    p_value = 1.0 if se == 0 else 2 * stats.norm.sf(abs(p1 - p2) / se)
    h = 2 * math.asin(math.sqrt(p1)) - 2 * math.asin(math.sqrt(p2))
    return p_value, h


def compare(fast: Sample, brute: Sample) -> dict:
    out = {}
    for what in ("lost", "particle"):
        k_fast, k_brute = getattr(fast, what), getattr(brute, what)
        p, h = two_proportion(k_fast, fast.beams, k_brute, brute.beams)
        out[what] = dict(fast=k_fast / fast.beams, brute=k_brute / brute.beams, p=p, h=h)
    out["range_ks_p"] = stats.ks_2samp(fast.range_m, brute.range_m).pvalue
    # Compare grid levels, not floats: float32(k * step) != float64(k * step), and the KS
    # statistic would see every tie as a shift.
    levels_fast, levels_brute = (np.rint(s.intensity / FINE_STEP) for s in (fast, brute))
    out["intensity_ks_p"] = stats.ks_2samp(levels_fast, levels_brute).pvalue
    return out


@pytest.fixture(scope="module")
def samples(kitti_frame):
    """Fast and brute samples per case, on frames FRAMES (computed once per module)."""
    profile = fine_kitti_profile()
    cache = {}

    def get(case):
        if case not in cache:
            weather, rate, mode = case
            fast, brute = Sample(), Sample()
            drawn = 0
            for i in FRAMES:
                xyz, intensity = fine_frame(kitti_frame, i)
                for seed in range(FAST_SEEDS):
                    run_fast(xyz, intensity, weather, rate, mode, 1000 * i + seed, fast, profile)
                drawn += run_brute(xyz, intensity, weather, rate, mode, 7 + i, brute, profile)
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
    assert brute.particle >= 100, "too few particle returns for the comparison to mean anything"
    for what in ("lost", "particle"):
        stat = result[what]
        assert stat["p"] > P_VALUE_FLOOR, f"{what} fraction differs: {stat}"
        assert abs(stat["h"]) <= MAX_COHEN_H, f"{what} fraction effect size too large: {stat}"
    assert result["range_ks_p"] > P_VALUE_FLOOR, "particle-return ranges differ"
    assert result["intensity_ks_p"] > P_VALUE_FLOOR, "particle-return intensities differ"


def test_comparison_rejects_a_brute_force_with_doubled_particle_reflectivity(samples, kitti_frame):
    """Power: the same statistics tell a wrong model (rho_p x 2) apart at p < 0.001."""
    weather, rate, mode = case = ("rain", 25.0, "strongest")
    fast, _, _ = samples(case)
    wrong = Sample()
    rho_p = RAIN_DEFAULTS.particle_reflectivity
    for i in FRAMES:
        xyz, intensity = fine_frame(kitti_frame, i)
        run_brute(xyz, intensity, weather, rate, mode, 99 + i, wrong, fine_kitti_profile(),
                  particle_reflectivity=2 * rho_p)  # fmt: skip
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
    params = FogParams().resolved_for(profile)
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

    table_range, table_power, _ = soft_return_peak(r0, alpha, beta, params)
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
        result = fog(xyz, intensity, visibility_m=visibility_m, sensor=profile, mode=mode,
                     rng=np.random.default_rng(0))  # fmt: skip
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
        np.testing.assert_allclose(fog_range, expected, atol=0.02)
