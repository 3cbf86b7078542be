"""Returns lost to dark glossy paint (incomplete echo) and false returns from another LiDAR's
pulses (crosstalk), both through the sensor's detection model (docs/augment.md §3).

Incomplete echo: every point of a class whose material has a clear-coat finish (vehicle
paint, materials.yaml) is repainted with a paint of reflectance rho_paint at 905 nm. Its
received power and intensity scale by k = rho_paint / rho_material where that is below 1.
Whether it is still detected follows the detection rule, conditioned on its clear-air
detection, as for weather: far and already-weak returns go first, not a random share.

Crosstalk: another LiDAR nearby fires pulses that are not synchronised with ours. A pulse that
reaches our receiver while one of our beams listens is timed as an echo, so it appears on
that beam's ray at a range uniform over the range gate [min_range, max_range]. A share of the
beams catches interfering light strong enough to detect. Interfering light is direct or
first-bounce laser light, far stronger than a diffuse echo, so it is the return the beam
reports (a PARTICLE outcome: a false return replaced the target's on the same ray). Its
reported intensity is that of an unknown power, drawn uniformly over the diffuse scale. Which
beams catch it follows the geometry of the interferer (`crosstalk`): targets close to both
sensors scatter the most of its light into our receiver.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lads.errors import ConfigError
from lads.physics.beams import assemble, dimmed, prepare_beams, resolve_sensor, unchanged
from lads.physics.materials import class_ids, class_roles, reflectance_for_labels
from lads.physics.result import Outcome, WeatherResult
from lads.sensors.profile import SensorProfile

# Default distance of the interfering LiDAR: a vehicle in the next lane or oncoming, m.
INTERFERER_RANGE_M = 10.0
# Below this, distances to the interferer and to our sensor do not shrink the weight further:
# a laser spot and a receiver aperture are centimetres wide, and real interferers sit metres
# away; 1 m keeps the weight finite without favouring the nearest returns without bound.
SCATTER_FLOOR_M = 1.0


def incomplete_echo(
    xyz: Any,
    intensity: Any,
    labels: Any,
    label_set: str,
    *,
    sensor: SensorProfile | str,
    rng: np.random.Generator,
    paint_reflectance: float,
    detection: str | float = "sensor",
) -> WeatherResult:
    """Vehicles repainted darker: their returns dimmed by k and lost where then undetected.

    Args:
        xyz: (N, 3) m. intensity: (N,) in the profile's encoding.
        labels: (N,) the frame's labels; label_set: their materials.yaml label set.
        sensor: profile or its name. rng: the frame's generator (detection draws only).
        paint_reflectance: rho_paint, diffuse reflectance of the new paint at 905 nm, in
            (0, 1].
        detection: the detection rule (`lads.physics.detection.resolve_detection`).

    Returns:
        WeatherResult: clear-coat points ATTENUATED or LOST, every other point KEPT.
    """
    if not 0.0 < paint_reflectance <= 1.0:
        raise ConfigError(
            f"incomplete_echo: paint_reflectance {paint_reflectance!r}; expected (0, 1]."
        )
    profile = resolve_sensor(sensor)
    beams = prepare_beams(xyz, intensity, profile)
    glossy_classes = np.fromiter(class_roles(label_set).clearcoat, dtype=np.int64)
    material = reflectance_for_labels(labels, label_set).astype(np.float64)
    # Only a darker paint changes anything: a lighter one leaves the recorded return alone.
    glossy = (
        beams.active
        & np.isin(class_ids(labels, label_set), glossy_classes)
        & (paint_reflectance < material)
    )
    if not glossy.any():
        return unchanged(beams, profile)
    ratio = np.ones(beams.range_m.size)
    ratio[glossy] = paint_reflectance / material[glossy]
    return dimmed(beams, profile, ratio, glossy, detection, rng)


def crosstalk(
    xyz: Any,
    intensity: Any,
    *,
    sensor: SensorProfile | str,
    rng: np.random.Generator,
    interfered_share: float,
    interferer_range_m: float = INTERFERER_RANGE_M,
    interferer_azimuth_deg: float | None = None,
) -> WeatherResult:
    """False returns from an unsynchronised LiDAR nearby, on `interfered_share` of the beams.

    The interferer sits at `interferer_range_m` from our sensor, at its height. Our beam
    whose target S lies at r = |S| catches its light scattered by S with a power
    ~ rho(S) / (|S - Q|^2 r^2): the interferer's spot irradiance falls with its distance to
    S, and the scattered light with ours. So the interfered beams are drawn, without
    replacement, with that weight: they gather on targets near both sensors, on the
    interferer's side (Popko et al. 2020: the risk rises steeply for targets close to and
    between the two scanners).

    Args:
        xyz: (N, 3) m. intensity: (N,) in the profile's encoding.
        sensor: profile or its name (its range gate and intensity encoding).
        rng: the frame's generator: the interferer's azimuth (unless given), which beams,
            the false ranges and intensities.
        interfered_share: share of the frame's beams that catch interfering light, [0, 1].
        interferer_range_m: distance of the interfering sensor, m (> 0).
        interferer_azimuth_deg: its azimuth atan2(y, x), deg; None draws it uniformly.

    Returns:
        WeatherResult: interfered beams PARTICLE at their false range, the rest KEPT.
    """
    _check_crosstalk(interfered_share, interferer_range_m)
    profile = resolve_sensor(sensor)
    beams = prepare_beams(xyz, intensity, profile)
    active = np.flatnonzero(beams.active)
    count = int(round(interfered_share * active.size))
    azimuth = (
        rng.uniform(-180.0, 180.0) if interferer_azimuth_deg is None else interferer_azimuth_deg
    )
    if count == 0:
        return unchanged(beams, profile)
    weight = _scatter_weight(beams, active, interferer_range_m, azimuth)
    hit = _weighted_draw(rng, active, weight, count)
    outcome = np.full(beams.range_m.size, Outcome.KEPT, dtype=np.uint8)
    outcome[hit] = Outcome.PARTICLE
    range_m = beams.range_m.copy()
    range_m[hit] = rng.uniform(profile.min_range_m, profile.max_range_m, size=count)
    reflectivity = profile.intensity.to_reflectivity(beams.intensity)
    reflectivity[hit] = rng.uniform(0.0, 1.0, size=count)
    return assemble(
        beams,
        profile,
        outcome=outcome,
        range_m=range_m,
        reflectivity=reflectivity,
        extinction_per_m=0.0,
        detection_threshold=float("nan"),
    )


def _check_crosstalk(interfered_share: float, interferer_range_m: float) -> None:
    """ConfigError unless the share lies in [0, 1] and the distance is finite and > 0."""
    if not 0.0 <= interfered_share <= 1.0:
        raise ConfigError(f"crosstalk: interfered_share {interfered_share!r}; expected [0, 1].")
    if not 0.0 < interferer_range_m < np.inf:
        raise ConfigError(
            f"crosstalk: interferer_range_m {interferer_range_m!r}; expected a distance > 0 m."
        )


def _weighted_draw(
    rng: np.random.Generator, rows: np.ndarray, weight: np.ndarray, count: int
) -> np.ndarray:
    """(count,) sorted rows drawn without replacement with probability ~ weight
    (Efraimidis-Spirakis: keys u^(1/w), the largest kept; one uniform per row)."""
    keys = np.log(rng.random(rows.size)) / weight
    return np.sort(rows[np.argpartition(-keys, count - 1)[:count]])


def _scatter_weight(
    beams: Any, active: np.ndarray, interferer_range_m: float, azimuth_deg: float
) -> np.ndarray:
    """(A,) float64 > 0: rho / (|S - Q|^2 r^2) of the active beams' targets S, with the
    interferer Q at the given range and azimuth in our sensor's horizontal plane. Distances
    are floored at SCATTER_FLOOR_M (an interferer's spot and our aperture are not points)."""
    a = np.radians(azimuth_deg)
    s = beams.xyz[active]
    x = s[:, 0] - interferer_range_m * np.cos(a)
    y = s[:, 1] - interferer_range_m * np.sin(a)
    z = s[:, 2].astype(np.float64)
    floor_sq = SCATTER_FLOOR_M**2
    to_q_sq = np.maximum(x * x + y * y + z * z, floor_sq)
    r = beams.range_m[active]
    r_sq = np.maximum(r * r, floor_sq)
    rho = np.maximum(beams.reflectivity[active], 1e-3)
    return rho / (to_q_sq * r_sq)  # type: ignore[no-any-return]
