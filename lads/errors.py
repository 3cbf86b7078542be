"""The LadsError hierarchy.

Every message says which file or input was at fault, what was expected and what to do.
The CLI maps these to exit codes; library code never prints or exits.
"""

from __future__ import annotations


class LadsError(Exception):
    """Base class of every error lads raises on purpose."""


class ConfigError(LadsError):
    """A parameter, profile or pipeline file is invalid."""


class SensorProfileError(ConfigError):
    """A sensor profile YAML is missing, malformed or inconsistent."""


class InputDataError(LadsError):
    """Point-cloud arrays handed to a library function are unusable as given."""


class InvalidPointsError(InputDataError):
    """Coordinates are NaN or infinite, or arrays have the wrong shape or dtype."""


class IntensityEncodingError(InputDataError):
    """Intensities lie outside the sensor profile's declared encoding."""


class PhysicsError(LadsError):
    """A physics computation was asked for outside its domain of validity."""
