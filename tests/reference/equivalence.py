"""Shared machinery of the fast-vs-brute-force comparison (tests and `make bench`).

See tests/realdata/test_equivalence.py for the statistics and why they are chosen.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from scipy import stats

from lads.physics.beams import prepare_beams
from lads.physics.particles import resolve_optics
from lads.physics.result import Outcome
from lads.physics.weather import RAIN_DEFAULTS, SNOW_DEFAULTS, rain, snow, with_overrides
from lads.sensors.profile import IntensityEncoding, load_profile
from tests.reference import particles_bruteforce as bf

FRAMES = (0, 1)
FAST_SEEDS = 24
P_VALUE_FLOOR = 1e-3
MAX_COHEN_H = 0.02
WEATHER = {"rain": (rain, RAIN_DEFAULTS), "snow": (snow, SNOW_DEFAULTS)}
# (weather, rate mm/h, mode, detection rule). The frame-calibrated threshold lets rain drops
# return often enough to test the particle sampler; the sensor's limit tests the conditional
# survival of targets (and, in snow, flakes at the sensor's limit).
CASES = [
    ("rain", 25.0, "strongest", "frame"),
    ("rain", 25.0, "last", "frame"),
    ("rain", 25.0, "strongest", "sensor"),
    ("snow", 10.0, "strongest", "sensor"),
    ("snow", 10.0, "last", "sensor"),
    ("rain", 25.0, "dual", "frame"),
    ("snow", 10.0, "dual", "sensor"),
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

    def add(self, outcome, ranges, intensities, second=None):
        """outcome: (N,) per beam (its first return); second: (N,) dual mode's second
        returns (LOST = none). `particle` counts particle returns of either."""
        self.beams += outcome.size
        self.lost += int((outcome == LOST).sum())
        self.particle += int((outcome == PARTICLE).sum())
        if second is not None:
            self.particle += int((second == PARTICLE).sum())
        self.ranges.append(np.asarray(ranges, dtype=np.float64))
        self.intensities.append(np.asarray(intensities, dtype=np.float64))

    @property
    def range_m(self):
        return np.concatenate(self.ranges)

    @property
    def intensity(self):
        return np.concatenate(self.intensities)


def fine_frame(xyz, intensity):
    """A real frame on the fine encoding: stored zeros -> the 0.005 KITTI assumes for them."""
    floor = load_profile("hdl64e").intensity.detection_floor
    return xyz, np.where(intensity == 0, np.float32(floor), intensity)


def params_for(weather, detection):
    return with_overrides(WEATHER[weather][1], detection_threshold=detection)


def run_fast(xyz, intensity, weather, rate, mode, detection, seed, sample, profile):
    simulate, params = WEATHER[weather][0], params_for(weather, detection)
    t = time.perf_counter()
    result = simulate(
        xyz,
        intensity,
        rate_mm_h=rate,
        sensor=profile,
        mode=mode,
        params=params,
        rng=np.random.default_rng(seed),
    )
    sample.seconds += time.perf_counter() - t
    first = np.r_[True, np.diff(result.source_index) != 0]
    outcome = np.full(len(xyz), LOST, dtype=np.uint8)
    outcome[result.source_index[first]] = result.outcome[first]
    second = np.full(len(xyz), LOST, dtype=np.uint8)
    second[result.source_index[~first]] = result.outcome[~first]
    is_particle = result.outcome == PARTICLE
    sample.add(
        outcome,
        np.linalg.norm(result.xyz[is_particle].astype(np.float64), axis=1),
        result.intensity[is_particle],
        second=second,
    )


def run_brute(xyz, intensity, weather, rate, mode, detection, seed, sample, profile, **wrong):
    beams = prepare_beams(xyz, intensity, profile)
    optics = resolve_optics(beams, profile, rate, params_for(weather, detection))
    constants = bf.Constants.from_optics(optics)
    constants = dataclasses.replace(constants, **wrong)
    rho_out = profile.intensity.to_reflectivity(beams.intensity)
    t = time.perf_counter()
    res = bf.simulate(beams, rho_out, constants, mode, np.random.default_rng(seed))
    sample.seconds += time.perf_counter() - t
    is_particle = res.outcome == PARTICLE
    second = res.second_outcome == PARTICLE
    sample.add(
        res.outcome,
        np.r_[res.range_m[is_particle], res.second_range_m[second]],
        on_fine_grid(np.r_[res.reflectivity[is_particle], res.second_reflectivity[second]]),
        second=res.second_outcome,
    )
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
