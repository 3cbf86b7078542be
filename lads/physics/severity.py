"""Severity presets: light / moderate / heavy rain, snow and fog as physical parameters.

A preset is a name for one value of the weather's physical parameter, nothing more: the
stage still runs on the rate (mm/h) or visibility (m), and the build records both (the
pipeline file in the output tree, its dataset card). The values and their sources are in
docs/physics.md ("Severity presets"):

- rain, rate in mm/h: the American Meteorological Society's intensity classes (light up to
  2.5 mm/h, moderate 2.6-7.6, heavy above 7.6); light and moderate sit inside their class,
  heavy is 25 mm/h, in the range LiDAR rain simulations use (30-33 mm/h).
- snow, water-equivalent rate in mm/h: the three snowfall rates of Robo3D's snow corruption
  (0.5, 1.0, 2.5), which span Hahner et al.'s snowfall simulator (0.5-2.5 mm/h), so the
  sets can be compared.
- fog, meteorological optical range in m: 600, 150 and 50 m, i.e. extinction about 0.005, 0.02
  and 0.06 1/m (alpha = ln(20) / MOR), levels 1, 3 and 5 of 3D_Corruptions_AD's fog; all are
  fog by the WMO's definition (MOR < 1000 m).
- wet ground, water film in mm: 0.2 (damp: the texture of dense asphalt, ~1 mm, partly
  filled), 0.5 and 1.2 mm (the texture covered; Hahner et al. 2022's wet-ground default is
  1-1.2 mm), all below the ~2.5 mm where aquaplaning starts.
- beam missing, the share of lasers that fail: 0.25, 0.5 and 0.75, i.e. Robo3D's beam-missing
  levels (16, 32 and 48 of 64 beams dropped).
- motion distortion, the vehicle's speed in m/s with an uncompensated sweep: 5 m/s (18 km/h,
  slow traffic), 14 m/s (50 km/h, the usual urban limit) and 28 m/s (100 km/h, motorway); at
  10 Hz the seam behind the vehicle then opens by 0.5, 1.4 and 2.8 m.
- incomplete echo, the 905 nm reflectance of the paint vehicles get: 0.25 (dark grey), 0.10
  and 0.04 (black: the dark paint of materials.yaml, ECOSTRESS 3.96 %), against the 0.52 of
  the shipped vehicle paint.
- crosstalk, the share of beams that catch another LiDAR's pulses: 0.6, 0.8 and 1.0 %, Robo3D's
  crosstalk levels.
"""

from __future__ import annotations

from typing import Any

from lads.errors import ConfigError

SEVERITIES: tuple[str, ...] = ("light", "moderate", "heavy")

# weather -> (its physical parameter, value per severity).
PRESETS: dict[str, tuple[str, dict[str, float]]] = {
    "rain": ("rate_mm_h", {"light": 1.0, "moderate": 5.0, "heavy": 25.0}),
    "snow": ("rate_mm_h", {"light": 0.5, "moderate": 1.0, "heavy": 2.5}),
    "fog": ("visibility_m", {"light": 600.0, "moderate": 150.0, "heavy": 50.0}),
    "wet_ground": ("water_film_mm", {"light": 0.2, "moderate": 0.5, "heavy": 1.2}),
    "beam_missing": ("lost_channel_share", {"light": 0.25, "moderate": 0.5, "heavy": 0.75}),
    "motion_distortion": ("speed_m_s", {"light": 5.0, "moderate": 14.0, "heavy": 28.0}),
    "incomplete_echo": ("paint_reflectance", {"light": 0.25, "moderate": 0.10, "heavy": 0.04}),
    "crosstalk": ("interfered_share", {"light": 0.006, "moderate": 0.008, "heavy": 0.010}),
}


def preset(weather: str, severity: str) -> tuple[str, float]:
    """(parameter name, value) of a weather's severity preset.

    Raises:
        ConfigError: a weather without presets or an unknown severity.
    """
    if weather not in PRESETS:
        raise ConfigError(
            f"severity: '{weather}' has no presets; presets exist for {sorted(PRESETS)}."
        )
    if severity not in SEVERITIES:
        raise ConfigError(f"severity {severity!r}: expected one of {', '.join(SEVERITIES)}.")
    key, values = PRESETS[weather]
    return key, values[severity]


def with_severity(weather: str, params: dict[str, Any], where: str) -> dict[str, Any]:
    """A weather stage's parameters with its `severity` (if any) resolved: the preset's
    value is filled in beside the name, so both are recorded.

    Raises:
        ConfigError: unknown severity, or an explicit value that differs from the preset's
            (give one or the other).
    """
    if params.get("severity") is None:
        return dict(params)
    try:
        key, value = preset(weather, params["severity"])
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    given = params.get(key)
    if given is not None and given != value:
        raise ConfigError(
            f"{where}: severity '{params['severity']}' means {key} = {value:g} for {weather}, "
            f"but {key} = {given!r} is also given; give one of them."
        )
    return {**params, key: value}
