"""Physical anchors of the weather models (docs/physics.md §2-§7) and their basic invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lads.physics.beams import auto_threshold, prepare_beams
from lads.physics.fog import (
    FogParams,
    backscatter_from_visibility,
    extinction_from_visibility,
    soft_return_peak,
)
from lads.physics.mie import efficiencies, extinction_efficiency, extinction_per_m
from lads.physics.particles import resolve_optics
from lads.physics.psd import marshall_palmer
from lads.physics.result import Outcome
from lads.physics.thinning import sample_winning_particles
from lads.physics.weather import (
    FOG_DEFAULTS,
    RAIN_DEFAULTS,
    SNOW_DEFAULTS,
    fog,
    rain,
    snow,
    with_overrides,
)
from lads.sensors.profile import load_profile
from tests.conftest import street_frame
from tests.reference import fog_bruteforce as fb

DB_PER_KM = math.log(10) / 10 / 1000  # 1 dB/km in 1/m (2.303e-4)
LISA_THRESHOLD = 0.9 / 200.0**2  # docs/physics.md §4: a 90 % target is just detected at 200 m
PRECIPITATION = {"rain": (rain, RAIN_DEFAULTS), "snow": (snow, SNOW_DEFAULTS)}


@pytest.fixture(scope="module")
def street():
    return street_frame(load_profile("hdl64e"))


def rain_alpha(rate_mm_h: float) -> float:
    return extinction_per_m(marshall_palmer(rate_mm_h), "water", 905.0)


# --- extinction ---------------------------------------------------------------------------


@pytest.mark.parametrize("rate", [1.0, 2.0, 5.0, 10.0, 25.0, 50.0, 100.0])
def test_rain_extinction_is_within_10_percent_of_ulbrich_atlas(rate):
    """Ulbrich-Atlas: 1.45 R^0.64 dB/km; Marshall-Palmer + Mie lies 5-9 % above it."""
    ulbrich_atlas = 1.45 * rate**0.64 * DB_PER_KM
    assert rain_alpha(rate) == pytest.approx(ulbrich_atlas, rel=0.10)


def test_two_way_transmission_over_100_m_of_25_mm_h_rain_is_0_57():
    """docs/physics.md §3 table: T^2 = 0.573 at 100 m (alpha = 2.78e-3 /m = pi N0 / Lambda^3).

    Tolerance 0.01 absolute, i.e. alpha within ~1 %: enough for the two effects the closed
    form ignores (Q_ext slightly above 2 and the D >= 0.05 mm cut), small enough to catch a
    wrong unit, a halved size parameter or a radius/diameter slip.
    """
    assert math.exp(-2 * rain_alpha(25.0) * 100.0) == pytest.approx(0.573, abs=0.01)


def test_mie_extinction_efficiency_tends_to_2_for_large_spheres():
    diameters_mm = np.array([0.1, 0.5, 0.8, 2.0, 5.0])  # x = pi D / lambda from ~350 to 17000
    q = extinction_efficiency("water", diameters_mm, 905.0)
    np.testing.assert_allclose(q, 2.0, rtol=0.02)
    deviation = np.abs(q - 2.0)
    assert deviation[-1] < 0.005 and deviation[-1] < deviation[0]
    qext, _ = efficiencies("water", np.array([0.8]), 905.0)  # the Mie series itself
    assert qext[0] == pytest.approx(2.0, rel=0.01)


def test_mie_uses_the_full_diameter_size_parameter():
    """docs/physics.md §2 pitfall: Q_ext(1 um) = 2.23 with x = pi D / lambda, 0.46 with x halved."""
    assert extinction_efficiency("water", np.array([1e-3]), 905.0)[0] == pytest.approx(
        2.23, abs=0.05
    )


# --- rain and snow on a frame -------------------------------------------------------------


def outcome_fractions(result, n):
    counts = result.counts()
    return counts["lost"] / n, counts["particle"] / n


@pytest.mark.parametrize("weather", ["rain", "snow"])
def test_particle_returns_and_target_losses_rise_with_rate(street, weather):
    """With the frame threshold: more particle returns, more beams lose the target."""
    xyz, intensity = street
    simulate, params = PRECIPITATION[weather]
    params = with_overrides(params, detection_threshold="frame")
    lost, particle = [], []
    for rate in (1.0, 5.0, 25.0, 100.0):
        result = simulate(
            xyz,
            intensity,
            rate_mm_h=rate,
            sensor="hdl64e",
            params=params,
            rng=np.random.default_rng(1),
        )
        lo, pa = outcome_fractions(result, len(xyz))
        lost.append(lo)
        particle.append(pa)
    target_gone = np.add(lost, particle)
    assert np.all(np.diff(particle) > 0), particle
    assert np.all(np.diff(target_gone) > 0), target_gone
    assert particle[-1] > 0.001  # at 1 mm/h a street frame may show no drop at all


@pytest.mark.parametrize("weather", ["rain", "snow"])
def test_with_the_sensor_limit_far_weak_targets_go_first_and_loss_rises_with_rate(street, weather):
    """docs/physics.md §9.7: the default rule loses more with the rate, far targets first
    (beyond 40 m they are a few % of the street's points and a large share of its losses)."""
    xyz, intensity = street
    simulate, _ = PRECIPITATION[weather]
    r = np.linalg.norm(xyz.astype(np.float64), axis=1)
    lost, far_share = [], []
    rates = (1.0, 5.0, 25.0, 100.0) if weather == "rain" else (0.5, 1.0, 2.5, 5.0)
    for rate in rates:
        result = simulate(
            xyz, intensity, rate_mm_h=rate, sensor="hdl64e", rng=np.random.default_rng(1)
        )
        lost.append(result.lost_index.size / len(xyz))
        far_share.append(float((r[result.lost_index] > 40.0).mean()) if lost[-1] else 1.0)
    assert np.all(np.diff(lost) > 0), lost
    assert lost[-1] > 0.001
    far_in_frame = float((r > 40.0).mean())
    assert far_share[0] > 5 * far_in_frame, (far_share, far_in_frame)


@pytest.mark.parametrize("weather", ["rain", "snow"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lost_fraction_rises_with_rate_at_lisa_fixed_threshold(street, weather, seed):
    """docs/physics.md §5.1: with P_min = 0.9/200^2 the lost fraction grows with the rate.

    (With the auto threshold the lost count is tiny and can even fall with the rate, since
    particle returns take over beams whose target dropped below P_min.)
    """
    xyz, intensity = street
    simulate, params = PRECIPITATION[weather]
    params = with_overrides(params, detection_threshold=LISA_THRESHOLD)
    lost = []
    for rate in (1.0, 10.0, 25.0, 100.0):
        result = simulate(
            xyz,
            intensity,
            rate_mm_h=rate,
            sensor="hdl64e",
            params=params,
            rng=np.random.default_rng(seed),
        )
        lost.append(outcome_fractions(result, len(xyz))[0])
    assert np.all(np.diff(lost) > 0), lost


def test_fog_returns_rise_as_visibility_falls(street):
    xyz, intensity = street
    for mode in ("strongest", "last"):
        fog_share = [
            outcome_fractions(
                fog(
                    xyz,
                    intensity,
                    visibility_m=v,
                    sensor="hdl64e",
                    mode=mode,
                    rng=np.random.default_rng(0),
                ),
                len(xyz),
            )[1]
            for v in (2000.0, 500.0, 100.0, 50.0, 20.0)
        ]
        # Thin fog's echo stays below the sensor's limit; denser fog returns more often.
        assert fog_share[0] == 0.0, (mode, fog_share)
        assert np.all(np.diff(fog_share) >= 0) and fog_share[-1] > fog_share[2] > 0, fog_share


def test_dense_fog_loses_beams_whose_echo_the_sensor_misses(street):
    """docs/physics.md §9.7: the fog echo is detected with probability p(P_f), so in dense
    fog some beams lose even near, bright targets and return nothing; thin fog takes only
    far targets that were already close to the sensor's limit."""
    xyz, intensity = street
    profile = load_profile("hdl64e")
    range_m = np.linalg.norm(xyz, axis=1)
    rho = np.maximum(
        profile.intensity.to_reflectivity(intensity), profile.intensity.detection_floor
    )
    above_limit = rho / range_m**2 / profile.detection.power
    lost = {
        v: fog(
            xyz, intensity, visibility_m=v, sensor=profile, rng=np.random.default_rng(0)
        ).lost_index
        for v in (2000.0, 20.0)
    }
    dense, thin = lost[20.0], lost[2000.0]
    assert dense.size > 0.005 * len(xyz)
    assert above_limit[dense].max() > 10 and np.median(range_m[dense]) < 30
    # Thin fog: only targets within a few times the limit, far beyond the street's typical.
    far = 3 * np.median(range_m)
    assert thin.size and above_limit[thin].max() < 5 and np.median(range_m[thin]) > far


# --- clear air and reproducibility ----------------------------------------------------------


def assert_unchanged(result, xyz, intensity):
    assert result.xyz.tobytes() == np.asarray(xyz, dtype=np.float32).tobytes()
    assert result.intensity.tobytes() == np.asarray(intensity, dtype=np.float32).tobytes()
    assert np.all(result.outcome == Outcome.KEPT)
    assert result.lost_index.size == 0
    np.testing.assert_array_equal(result.source_index, np.arange(len(xyz)))


@pytest.mark.parametrize("weather", ["rain", "snow"])
@pytest.mark.parametrize("mode", ["strongest", "last"])
def test_rate_zero_returns_the_input_byte_for_byte(street, weather, mode):
    xyz, intensity = street
    result = PRECIPITATION[weather][0](
        xyz, intensity, rate_mm_h=0.0, sensor="hdl64e", mode=mode, rng=np.random.default_rng(0)
    )
    assert_unchanged(result, xyz, intensity)


@pytest.mark.parametrize("mode", ["strongest", "last"])
def test_infinite_visibility_returns_the_input_byte_for_byte(street, mode):
    xyz, intensity = street
    result = fog(
        xyz,
        intensity,
        visibility_m=math.inf,
        sensor="hdl64e",
        mode=mode,
        rng=np.random.default_rng(0),
    )
    assert_unchanged(result, xyz, intensity)


@pytest.mark.parametrize("weather", ["rain", "snow", "fog"])
def test_a_fixed_threshold_drops_the_same_clear_air_returns_at_rate_zero_as_near_it(
    street, weather
):
    """docs/physics.md §5.2: LISA's fixed threshold drops the clear-air returns weaker than
    it at any rate; rate 0 (visibility inf) must not be the one exception, or a sweep over
    rates jumps between 0 and the smallest rate. The returns it keeps keep their bytes."""
    xyz, intensity = street
    params = with_overrides(
        FOG_DEFAULTS if weather == "fog" else PRECIPITATION[weather][1],
        detection_threshold=LISA_THRESHOLD,
    )

    def run(strength):
        call = fog if weather == "fog" else PRECIPITATION[weather][0]
        key = "visibility_m" if weather == "fog" else "rate_mm_h"
        return call(
            xyz,
            intensity,
            sensor="hdl64e",
            params=params,
            rng=np.random.default_rng(0),
            **{key: strength},
        )

    clear, near = (
        run(math.inf if weather == "fog" else 0.0),
        run(1e12 if weather == "fog" else 1e-9),
    )
    beams = prepare_beams(xyz, intensity, load_profile("hdl64e"))
    weak = np.flatnonzero(beams.active & (beams.clear_power < LISA_THRESHOLD))
    assert weak.size > 0  # the street has far, dark returns below 0.9 / 200^2
    np.testing.assert_array_equal(clear.lost_index, weak)
    np.testing.assert_array_equal(near.lost_index, weak)
    kept = np.setdiff1d(np.arange(len(xyz)), weak)
    np.testing.assert_array_equal(clear.source_index, kept)
    assert np.all(clear.outcome == Outcome.KEPT)
    assert clear.xyz.tobytes() == np.asarray(xyz, np.float32)[kept].tobytes()
    assert clear.intensity.tobytes() == np.asarray(intensity, np.float32)[kept].tobytes()
    assert clear.detection_threshold == LISA_THRESHOLD


@pytest.mark.parametrize(
    "call",
    [
        lambda x, i, g: rain(x, i, rate_mm_h=25.0, sensor="hdl64e", rng=g),
        lambda x, i, g: snow(x, i, rate_mm_h=5.0, sensor="hdl64e", rng=g, mode="last"),
        lambda x, i, g: fog(x, i, visibility_m=80.0, sensor="hdl64e", rng=g),
    ],
    ids=["rain", "snow-last", "fog"],
)
def test_same_generator_state_gives_the_same_bytes(street, call):
    xyz, intensity = street
    first = call(xyz, intensity, np.random.default_rng(123))
    second = call(xyz, intensity, np.random.default_rng(123))
    other = call(xyz, intensity, np.random.default_rng(124))
    for name in ("xyz", "intensity", "source_index", "outcome", "lost_index"):
        assert getattr(first, name).tobytes() == getattr(second, name).tobytes(), name
    assert first.xyz.tobytes() != other.xyz.tobytes(), "the generator is actually used"


def test_auto_threshold_loses_nothing_in_clear_air_unlike_lisa_fixed_threshold(street):
    """The auto threshold is the weakest clear-air return, so every input beam is detectable;
    LISA's fixed 0.9/200^2 would drop far dark returns before any weather (docs/physics.md §5.2)."""
    xyz, intensity = street
    profile = load_profile("hdl64e")
    beams = prepare_beams(xyz, intensity, profile)
    p_min = auto_threshold(beams)
    assert np.all(beams.clear_power >= p_min)
    # Weather so light that no target can drop by more than 1e-6 of its power ...
    rate = 1e-9
    light = rain(xyz, intensity, rate_mm_h=rate, sensor=profile, rng=np.random.default_rng(0))
    optics = resolve_optics(beams, profile, rate, RAIN_DEFAULTS)
    drop = 1 - math.exp(-2 * optics.particles.alpha_per_m * beams.range_m.max())
    assert drop < 1e-6
    # ... loses at most the beams sitting exactly at the threshold ...
    at_threshold = int(np.sum(beams.clear_power * (1 - drop) < p_min))
    assert light.lost_index.size <= at_threshold <= 10
    # ... while the fixed threshold loses several per mille of the frame.
    lisa_params = with_overrides(RAIN_DEFAULTS, detection_threshold=LISA_THRESHOLD)
    lisa = rain(
        xyz,
        intensity,
        rate_mm_h=rate,
        sensor=profile,
        rng=np.random.default_rng(0),
        params=lisa_params,
    )
    assert lisa.lost_index.size > 0.003 * len(xyz)


# --- fog soft return ------------------------------------------------------------------------


@pytest.mark.parametrize("visibility_m", [30.0, 300.0, 3000.0])
def test_fog_peak_table_matches_direct_integration_within_1_percent(visibility_m):
    params = FogParams().resolved_for(load_profile("hdl64e"))  # R1 = 0.9 m, R2 = 1.0 m
    alpha = extinction_from_visibility(visibility_m)
    beta = backscatter_from_visibility(visibility_m, params)
    r0 = np.array([0.92, 0.97, 1.0, 1.05, 1.5, 2.5, 4.0, 5.5, 6.9, 7.2, 15.0, 90.0])
    peak_range, peak_power, _ = soft_return_peak(r0, alpha, beta, params)
    constants = fb.FogConstants.from_params(alpha, beta, params)
    brute = np.array([fb.soft_return_peak(float(r), constants) for r in r0])
    np.testing.assert_allclose(peak_power, brute[:, 1], rtol=0.01)
    np.testing.assert_allclose(peak_range, brute[:, 0], atol=0.01)
    # Below R1 there is no fog in front of the target.
    _, none, _ = soft_return_peak(np.array([0.5, 0.89]), alpha, beta, params)
    np.testing.assert_array_equal(none, 0.0)


# --- the thinned sampler against the cone volume ---------------------------------------------


@pytest.mark.parametrize(
    ("r0", "divergence_mrad"),
    [
        (0.95, 30.0),
        (1.5, 30.0),
        (5.0, 30.0),
        (40.0, 3.0),
        (25.0, 30.0),
    ],
)
def test_thinned_sampler_draws_the_cone_volume_times_the_particle_density(r0, divergence_mrad):
    """With a floor below every particle's power, every particle in the cone is 'winning':
    the mean count per beam must be N_total * pi (theta/2)^2 (r0^3 - r_min^3) / 3 (LISA)."""
    xyz = np.array([[r0, 0.0, 0.0]], dtype=np.float32)
    profile = load_profile("hdl64e")
    beams = prepare_beams(xyz, np.array([0.5], dtype=np.float32), profile)
    # A hard cut at R1 (no overlap ramp), so the cone volume is the textbook one.
    params = with_overrides(
        RAIN_DEFAULTS, beam_divergence_mrad=divergence_mrad, min_range_m=0.9, overlap_full_m=0.9
    )
    optics = resolve_optics(beams, profile, 25.0, params).particles
    theta, r_min = optics.divergence_rad, optics.min_range_m
    per_beam = optics.psd.number_per_m3 * math.pi * (theta / 2) ** 2 * (r0**3 - r_min**3) / 3
    n_beams = int(math.ceil(100_000 / per_beam))  # ~1e5 expected particles: 0.3 % noise
    # s = sqrt(floor / rho_p) = 1e-6, the table's smallest column: at these ranges even a
    # D_min particle returns more than the floor.
    floor = np.full(n_beams, 1.0001e-12 * optics.particle_reflectivity)
    owner, _, _ = sample_winning_particles(
        optics, np.full(n_beams, r0), floor, np.random.default_rng(0)
    )
    assert owner.size / n_beams == pytest.approx(per_beam, rel=0.01)
