"""The parameters each pipeline stage accepts, and their checks (`lads.config` reads them).

`STAGE_PARAMS` is the one table of stage parameters: per stage, each parameter's kind, which
`check_stage` validates; unknown or missing parameters are errors naming the stage.
"""

from __future__ import annotations

import math
from typing import Any

from lads.errors import ConfigError, LadsError
from lads.physics.detection import resolve_detection
from lads.physics.severity import PRESETS, SEVERITIES, with_severity
from lads.transfer.window import check_neighbours

RETURN_MODES = ("strongest", "last", "dual")
# Where a motion-distortion stage may take the vehicle's motion from besides its parameters.
EGO_MOTIONS = ("poses",)

# Parameters each stage accepts, with a validator per parameter.
_WEATHER_PARAMS = {
    "mode": "return_mode", "severity": "severity", "settings": "settings",
    "detection": "detection",
}  # fmt: skip
STAGE_PARAMS: dict[str, dict[str, str]] = {
    "rain": {"rate_mm_h": "nonneg", **_WEATHER_PARAMS},
    "snow": {"rate_mm_h": "nonneg", **_WEATHER_PARAMS},
    "fog": {"visibility_m": "visibility", **_WEATHER_PARAMS},
    "wet_ground": {"water_film_mm": "film", "severity": "severity", "detection": "detection"},
    "intensity": {"model": "text", "target": "optional_text", "device": "device"},
    "sensor": {"target": "profile", "neighbours": "neighbours"},
    "beam_missing": {
        "lost_channel_share": "share",
        "channels": "channel_list",
        "severity": "severity",
    },
    "motion_distortion": {
        "speed_m_s": "optional_number",
        "yaw_rate_deg_s": "optional_number",
        "velocity_m_s": "vector3",
        "angular_velocity_deg_s": "vector3",
        "ego_motion": "ego_motion",
        "sweep_period_s": "optional_period",
        "seam_azimuth_deg": "optional_number",
        "severity": "severity",
    },
    "incomplete_echo": {
        "paint_reflectance": "reflectance",
        "severity": "severity",
        "detection": "detection",
    },
    "crosstalk": {
        "interfered_share": "share",
        "interferer_range_m": "optional_distance",
        "interferer_azimuth_deg": "optional_number",
        "severity": "severity",
    },
}
_OPTIONAL_KINDS = {"return_mode", "optional_text", "device", "severity", "settings", "detection",
                   "neighbours", "channel_list", "optional_number", "optional_period",
                   "vector3", "ego_motion", "optional_distance"}  # fmt: skip
# (stage, parameter) -> the parameter that makes it unneeded: fixed dead lasers need no share.
_GIVEN_BY = {("beam_missing", "lost_channel_share"): "channels"}
# Weather stages, and the sensor faults and artefacts that are not weather.
WEATHER_STAGES = ("rain", "snow", "fog", "wet_ground")
FAULT_STAGES = ("beam_missing", "motion_distortion", "incomplete_echo", "crosstalk")
# Stages whose physical strength a `severity` preset can give (lads.physics.severity).
SEVERITY_STAGES = WEATHER_STAGES + FAULT_STAGES
# The physical strengths a severity preset names (rate, visibility, water film).
STRENGTHS = tuple(sorted({key for key, _ in PRESETS.values()}))
DEVICES = ("cpu", "cuda")


# Kinds whose value is one of a fixed set: (the allowed values, what the message calls it).
_CHOICES: dict[str, tuple[tuple[Any, ...], str]] = {
    "device": (DEVICES, "device"),
    "severity": (SEVERITIES, "severity"),
    "return_mode": (RETURN_MODES, "mode is"),
    "ego_motion": ((None, *EGO_MOTIONS), "ego_motion"),
}
# Kinds that may be null (a default applies), checked as numbers otherwise.
_OPTIONAL_NUMBERS = ("optional_number", "optional_period", "optional_distance")


def _check_value(kind: str, value: Any, where: str) -> None:
    """Raise ConfigError naming `where` unless `value` is a valid parameter of `kind`."""
    if kind in _CHOICES:
        allowed, what = _CHOICES[kind]
        if value not in allowed:
            shown = tuple(v for v in allowed if v is not None)
            raise ConfigError(f"{where}: {what} {value!r}; expected one of {shown}.")
        return
    if kind in ("text", "optional_text", "settings"):
        _check_text(kind, value, where)
    elif kind in ("detection", "neighbours", "profile"):
        _check_reference(kind, value, where)
    elif kind in ("channel_list", "vector3"):
        _check_list(kind, value, where)
    elif not (kind in _OPTIONAL_NUMBERS and value is None):
        _check_number(kind, value, where)


def _check_text(kind: str, value: Any, where: str) -> None:
    """A non-empty string (optional_text: or None)."""
    if (value is None and kind == "optional_text") or (isinstance(value, str) and value):
        return
    if kind == "settings":
        raise ConfigError(f"{where}: expected the name of weather settings, got {value!r}.")
    raise ConfigError(f"{where}: expected a non-empty string, got {value!r}.")


def _check_reference(kind: str, value: Any, where: str) -> None:
    """A detection rule, a window size or a sensor profile, checked by their own readers."""
    if kind == "neighbours":
        check_neighbours(value, where)
        return
    try:
        if kind == "detection":
            resolve_detection(value, 1.0, 1.0, 1.0)
        else:
            from lads.sensors.profile import load_profile

            load_profile(value)
    except LadsError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _check_list(kind: str, value: Any, where: str) -> None:
    """None, or channel ids (integers >= 0), or three finite numbers (vector3)."""
    if value is None:
        return
    if kind == "channel_list":
        if isinstance(value, list | tuple) and all(
            isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in value
        ):
            return
        raise ConfigError(
            f"{where}: expected a list of channel ids (integers >= 0), got {value!r}."
        )
    numbers = isinstance(value, list | tuple) and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value
    )
    if not (numbers and len(value) == 3):
        raise ConfigError(f"{where}: expected three finite numbers [x, y, z], got {value!r}.")


# The numeric kinds: what each accepts, and how a refusal reads.
_NUMBER_RULES: dict[str, tuple[Any, str]] = {
    "nonneg": (lambda v: 0 <= v < math.inf, "rate must be a finite number >= 0 mm/h"),
    "film": (lambda v: 0 <= v < math.inf, "water film must be a finite thickness >= 0 mm"),
    "reflectance": (lambda v: 0 < v <= 1, "expected a reflectance in (0, 1]"),
    "share": (lambda v: 0 <= v <= 1, "expected a share in [0, 1]"),
    "optional_number": (math.isfinite, "expected a finite number"),
    "optional_period": (lambda v: 0 < v < 10, "expected a sweep period in (0, 10) s"),
    "optional_distance": (lambda v: 0 < v < math.inf, "expected a finite distance > 0 m"),
    "visibility": (lambda v: v > 0, "visibility must be > 0 m (inf = clear air)"),
}


def _check_number(kind: str, value: Any, where: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise ConfigError(f"{where}: expected a number, got {value!r}.")
    accepts, refusal = _NUMBER_RULES.get(kind, (lambda v: True, ""))
    if not accepts(value):
        raise ConfigError(f"{where}: {refusal}, got {value}.")


def resolved(name: str, params: dict[str, Any], where: str) -> dict[str, Any]:
    """A weather stage's parameters with a `severity` preset's value filled in."""
    if name not in SEVERITY_STAGES or "severity" not in params:
        return params
    return with_severity(name, params, where)


def check_stage(name: str, params: dict[str, Any], where: str) -> None:
    accepted = STAGE_PARAMS.get(name)
    if accepted is None:
        raise ConfigError(
            f"{where}: unknown stage {name!r}; expected one of {sorted(STAGE_PARAMS)}."
        )
    unknown = sorted(set(params) - set(accepted))
    if unknown:
        raise ConfigError(
            f"{where}: stage {name!r} has unknown parameters {unknown}; "
            f"it accepts {sorted(accepted)}."
        )
    missing = [
        k
        for k, kind in accepted.items()
        if kind not in _OPTIONAL_KINDS
        and k not in params
        and params.get(_GIVEN_BY.get((name, k), "")) is None
    ]
    if missing:
        raise ConfigError(f"{where}: stage {name!r} needs {missing}.")
    for key, value in params.items():
        _check_value(accepted[key], value, f"{where}: {key}")
    if "settings" in params:
        from lads.physics.weather import settings_for

        try:
            settings_for(name, params["settings"])
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
