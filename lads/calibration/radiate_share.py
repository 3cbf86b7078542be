"""Which fog visibility makes clear HDL-32E frames look like RADIATE's foggy ones?

RADIATE's foggy frames (`lads.calibration.radiate`) have no clear twin, so the fog model is
run on other real HDL-32E frames (nuScenes, the same sensor) and two things a foggy frame
shows are compared, each as a function of the visibility (MOR):

- the **return share**: returns per fired beam; RADIATE's counted in the half of the sweep
  without the recording vehicle's structure (azimuth 0..180 deg, `radiate.CLEAN_AZIMUTH_DEG`),
  the simulated ones over the whole sweep;
- the **range profile**: how those returns spread over range bins.

Returns nearer than BODY_M are left out of both: in both datasets they are the vehicle's
own body. Each measure is taken over all channels and over channel bands
(`CHANNEL_BANDS`): RADIATE's vehicle blocks its steepest beams even in the clean half, so
the "upper" band, the beams that meet the road beyond ~9 m or pass above it, is the one
neither vehicle's structure reaches.

A visibility is fitted to one real frame by each measure alone (the grid value
closest to it) and scored on the other frames with both measures, so a model that can
match one only by missing the other shows it. The scenes differ (Edinburgh vs Boston and
Singapore streets), which both measures inherit: this is a comparison of shapes, not a
twin experiment.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.calibration.radiate import FIRINGS_PER_SWEEP, SENSOR, RadiateFrame, in_clean_half
from lads.errors import ConfigError
from lads.physics import weather as wx
from lads.sensors.profile import SensorProfile, load_profile

# Returns nearer than this are the recording vehicle's body (RADIATE: a spike at 0.5 m;
# nuScenes: the roof around LIDAR_TOP).
BODY_M = 1.5
RANGE_BINS_M = (BODY_M, 5.0, 10.0, 20.0, 40.0, np.inf)
# Visibilities tried (MOR, m): dense fog to light haze.
MOR_GRID_M = (6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 30.0, 50.0, 100.0, 200.0, 600.0)
FIT_MEASURES = ("share", "profile")
# Near-ground channels: HDL-32E beams between these elevations meet a flat road 5-9 m away
# (sensor ~2 m up); steeper ones are blocked by RADIATE's vehicle even in its clean half.
NEAR_GROUND_ELEVATION_DEG = (-20.5, -13.0)
# Channel bands by elevation: "steep" below NEAR_GROUND_ELEVATION_DEG (road within 5 m),
# "near_ground" within it, "upper" above it, "all" every channel.
CHANNEL_BANDS = ("all", "steep", "near_ground", "upper")


@dataclass(frozen=True, slots=True)
class ReturnProfile:
    """share: returns beyond BODY_M per fired beam; per_bin: (len(RANGE_BINS_M) - 1,) share
    of those returns per range bin (sums to 1, zeros when there are none)."""

    share: float
    per_bin: tuple[float, ...]

    @staticmethod
    def mean(profiles: Sequence[ReturnProfile]) -> ReturnProfile:
        """The mean share and mean per-bin shares of several profiles."""
        return ReturnProfile(
            float(np.mean([p.share for p in profiles])),
            tuple(float(v) for v in np.mean([p.per_bin for p in profiles], axis=0)),
        )

    def as_dict(self) -> dict[str, object]:
        return {
            "returns_per_fired_beam": round(self.share, 4),
            "share_per_range_bin": [round(v, 4) for v in self.per_bin],
        }


def returns_profile(xyz: npt.NDArray[np.floating], firings: int) -> ReturnProfile:
    """Profile of the returns xyz (N, 3) m out of `firings` fired beams."""
    if firings <= 0:
        raise ConfigError(f"firings = {firings}: expected the number of beams fired, > 0.")
    r = np.linalg.norm(np.asarray(xyz, dtype=np.float64), axis=1)
    r = r[r >= BODY_M]
    counts = np.histogram(r, bins=np.asarray(RANGE_BINS_M))[0]
    per_bin = counts / r.size if r.size else np.zeros(counts.size)
    return ReturnProfile(r.size / firings, tuple(float(v) for v in per_bin))


def clean_half(frame: RadiateFrame) -> npt.NDArray[np.float64]:
    """(M, 3) m: a RADIATE frame's returns in the half of the sweep free of the vehicle's
    structure (`radiate.CLEAN_AZIMUTH_DEG`), FIRINGS_PER_SWEEP / 2 firings per channel."""
    return frame.xyz.astype(np.float64)[in_clean_half(frame.xyz)]


def radiate_profile(frame: RadiateFrame, band: str = "all") -> ReturnProfile:
    """Profile of a RADIATE frame's clean half (half the beams of a sweep), over the
    channels of `band` (`CHANNEL_BANDS`)."""
    sensor = load_profile(SENSOR)
    return band_profile(clean_half(frame), FIRINGS_PER_SWEEP // 2, sensor, band)


def band_channels(sensor: SensorProfile, band: str) -> npt.NDArray[np.int64]:
    """The channels of `band` (`CHANNEL_BANDS`, by NEAR_GROUND_ELEVATION_DEG).

    Raises:
        ConfigError: an unknown band.
    """
    elevation = np.asarray(sensor.elevation_deg, dtype=np.float64)
    lo, hi = NEAR_GROUND_ELEVATION_DEG
    masks = {
        "all": np.ones(elevation.size, dtype=bool),
        "steep": elevation <= lo,
        "near_ground": (elevation > lo) & (elevation < hi),
        "upper": elevation >= hi,
    }
    if band not in masks:
        raise ConfigError(f"channel band {band!r}: expected one of {CHANNEL_BANDS}.")
    return np.flatnonzero(masks[band])


def band_profile(
    xyz: npt.NDArray[np.floating], firings_per_channel: int, sensor: SensorProfile, band: str
) -> ReturnProfile:
    """Profile of the returns xyz (N, 3) m on the channels of `band` (channel by the
    sensor's elevation table), out of firings_per_channel beams fired by each of them."""
    xyz = np.asarray(xyz, dtype=np.float64)
    channels = band_channels(sensor, band)
    if band != "all":
        xyz = xyz[np.isin(sensor.channel_of(xyz), channels)]
    return returns_profile(xyz, firings_per_channel * channels.size)


def near_ground_share(
    xyz: npt.NDArray[np.floating], firings_per_channel: int, sensor: SensorProfile
) -> float:
    """Returns beyond BODY_M per fired beam of the near-ground channels; xyz (N, 3) m."""
    return band_profile(xyz, firings_per_channel, sensor, "near_ground").share


def profile_distance(a: ReturnProfile, b: ReturnProfile) -> float:
    """Total-variation distance between two range profiles, in [0, 1]."""
    return 0.5 * float(np.abs(np.subtract(a.per_bin, b.per_bin)).sum())


def simulated_curves(
    frames: Sequence[tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]],
    firings_per_channel: int,
    sensor: SensorProfile,
    bands: Sequence[str] = ("all",),
    mor_grid_m: Sequence[float] = MOR_GRID_M,
) -> dict[str, dict[float, ReturnProfile]]:
    """Mean profile of the fogged clear frames (xyz (N, 3) m, intensity (N,)) per band and
    MOR (m), each frame firing firings_per_channel beams per channel.

    Fog runs with the shipped defaults (strongest return, the sensor's detection rule); frame
    k at every MOR draws from the generator seeded (k, MOR in mm), so curves are repeatable.
    """
    curves: dict[str, dict[float, ReturnProfile]] = {band: {} for band in bands}
    for mor in mor_grid_m:
        fogged = []
        for k, (xyz, intensity) in enumerate(frames):
            rng = np.random.default_rng([k, int(round(mor * 1000))])
            fogged.append(wx.fog(xyz, intensity, visibility_m=float(mor), sensor=sensor, rng=rng))
        for band in bands:
            curves[band][float(mor)] = ReturnProfile.mean(
                [band_profile(f.xyz, firings_per_channel, sensor, band) for f in fogged]
            )
    return curves


def fit_visibility(real: ReturnProfile, curve: dict[float, ReturnProfile], by: str) -> float:
    """The MOR (m) of `curve` closest to `real` by return share or by range profile.

    Raises:
        ConfigError: `by` not in FIT_MEASURES, or an empty curve.
    """
    if by not in FIT_MEASURES or not curve:
        raise ConfigError(
            f"fit by {by!r} on {len(curve)} visibilities: expected one of "
            f"{FIT_MEASURES} and a non-empty curve."
        )
    if by == "share":
        return min(curve, key=lambda mor: abs(curve[mor].share - real.share))
    return min(curve, key=lambda mor: profile_distance(curve[mor], real))
