"""What a weather simulation returns: output points plus their provenance."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt


class Outcome(IntEnum):
    """Fate of one beam (one input point) under weather; stored as uint8.

    KEPT: the hard-target return survives unchanged (no extinction on its path).
    ATTENUATED: the hard-target return survives with extinction-reduced intensity and
        weather-induced range noise.
    PARTICLE: a particle (rain drop, snow flake) or fog-volume return replaced the target
        return on this beam; the output point lies on the same ray at the particle range.
    LOST: no return above the detection threshold; never in `WeatherResult.outcome`, only
        used by writers that keep N unchanged and mark the point instead.
    RESAMPLED: a beam of another sensor (a sensor transfer, `lads.transfer`) that hit the
        surface a source return gave; its source index names that return, in the scan of
        the frame's window its provenance names.
    DISPLACED: the hard-target return survives but is reported at another position (a
        sweep distorted by the vehicle's motion, `lads.physics.sensor_faults`).
    """

    KEPT = 0
    ATTENUATED = 1
    PARTICLE = 2
    LOST = 3
    RESAMPLED = 4
    DISPLACED = 5


@dataclass(frozen=True, slots=True)
class WeatherResult:
    """Output of `lads.physics.weather.rain/snow/fog` for one frame of N input points.

    Attributes:
        xyz: (M, 3) float32, metres, sensor frame: one return per surviving beam (two where
            a dual-return beam's strongest and last returns differ).
        intensity: (M,) float32 in the sensor profile's own encoding.
        source_index: (M,) int64, index of the input point (beam) each output point came
            from; increasing, so output order follows input order (a dual-return beam's two
            returns are adjacent, strongest first). Labels and extra columns (ring, time)
            follow through it.
        outcome: (M,) uint8 `Outcome` code per output point (KEPT, ATTENUATED or PARTICLE).
        lost_index: (K,) int64, input points with no return; N = M + K - (second returns).
        extinction_per_m: extinction coefficient alpha used, in 1/m.
        detection_threshold: normalised detection threshold P_min used (reflectivity / m^2).
    """

    xyz: npt.NDArray[np.float32]
    intensity: npt.NDArray[np.float32]
    source_index: npt.NDArray[np.int64]
    outcome: npt.NDArray[np.uint8]
    lost_index: npt.NDArray[np.int64]
    extinction_per_m: float
    detection_threshold: float

    @property
    def second_returns(self) -> int:
        """Output points that are a beam's second (dual-mode) return."""
        return int(np.count_nonzero(np.diff(self.source_index) == 0))

    def counts(self) -> dict[str, int]:
        """Number of input beams per weather outcome (KEPT ... LOST), LOST included."""
        found = np.bincount(self.outcome, minlength=len(Outcome))
        found[Outcome.LOST] = self.lost_index.size
        return {o.name.lower(): int(found[o]) for o in Outcome if o <= Outcome.LOST}
