"""The corruption suite, by name (`lads.augment` and the `C-` build variants): which stage runs
each, the physical quantity its severity sets, and the names the robustness benchmarks use.

One table (`CORRUPTIONS`); the severity values themselves live in `lads.physics.severity`.
"""

from __future__ import annotations

from dataclasses import dataclass

from lads.errors import ConfigError
from lads.physics.severity import PRESETS, SEVERITIES


@dataclass(frozen=True, slots=True)
class CorruptionSpec:
    """One corruption of the suite.

    Attributes:
        name: the name users pass (`corrupt(..., corruption=name)`, `lads build --variant`).
        stage: the pipeline stage that runs it (`lads.stages.STAGES`).
        peer_names: what Robo3D / 3D_Corruptions_AD / MultiCorrupt call it.
        needs_labels: it reads per-point classes (wet ground lies on ground classes).
        adds_particles: it can replace returns by particle (rain, snow, fog) returns.
        summary: one line for listings.
    """

    name: str
    stage: str
    peer_names: tuple[str, ...]
    needs_labels: bool
    adds_particles: bool
    summary: str

    @property
    def has_presets(self) -> bool:
        """Whether severities name values of it (cross-sensor names a target sensor instead)."""
        return self.stage in PRESETS

    @property
    def parameter(self) -> str:
        """The physical quantity a severity preset sets (`lads.physics.severity.PRESETS`)."""
        return PRESETS[self.stage][0]

    def preset(self, severity: str) -> float:
        """The value of `parameter` at one severity."""
        return PRESETS[self.stage][1][severity]


def _spec(
    name: str,
    peers: tuple[str, ...],
    summary: str,
    *,
    labels: bool = False,
    particles: bool = False,
    stage: str | None = None,
) -> CorruptionSpec:
    return CorruptionSpec(name, stage or name, peers, labels, particles, summary)


CORRUPTIONS: dict[str, CorruptionSpec] = {
    spec.name: spec
    for spec in (
        _spec("fog", ("fog",), "Mie-scattering fog: attenuation, lost beams, fog returns",
              particles=True),
        _spec("rain", ("rain",), "falling rain: drop returns, attenuation, lost weak returns",
              particles=True),
        _spec("snow", ("snow",), "falling snow: flake returns, attenuation, lost weak returns",
              particles=True),
        _spec("wet_ground", ("wet ground",), "a water film on ground classes: darker road, "
              "lost grazing returns", labels=True),
        _spec("beam_missing", ("beam missing",), "dead lasers: every return of a share of the "
              "channels lost"),
        _spec("motion_distortion", ("motion_blur", "motion blur"), "rolling-shutter skew of a "
              "sweep taken while the vehicle moves"),
        _spec("crosstalk", ("cross_talk",), "another LiDAR's pulses: false returns at uniform "
              "range on a share of the beams", particles=True),
        _spec("incomplete_echo", ("incomplete echo",), "vehicles in dark paint: weak returns "
              "of clear-coat classes lost", labels=True),
        _spec("cross_sensor", ("cross-sensor", "cross sensor"), "the scan as another LiDAR "
              "(target=PROFILE) would have made it, ray-cast against the frame's surfaces",
              stage="sensor"),
    )
}  # fmt: skip


def corruption_spec(name: str) -> CorruptionSpec:
    """The spec of a corruption by its name or a peer's name for it.

    Raises:
        ConfigError: unknown name; the message lists the valid ones.
    """
    if name in CORRUPTIONS:
        return CORRUPTIONS[name]
    for spec in CORRUPTIONS.values():
        if name in spec.peer_names:
            return spec
    raise ConfigError(
        f"unknown corruption {name!r}; expected one of {', '.join(CORRUPTIONS)} "
        f"(severities: {', '.join(SEVERITIES)})."
    )
