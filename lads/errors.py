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


class PointFormatError(ConfigError):
    """A build cannot write the point record it was asked for (`--point-format`,
    `writer.point_format`): no sensor stage, a target without a native format, or a source
    format whose own tooling cannot read the target's record."""


class InputDataError(LadsError):
    """Point-cloud arrays handed to a library function are unusable as given."""


class InvalidPointsError(InputDataError):
    """Coordinates are NaN or infinite, or arrays have the wrong shape or dtype."""


class AugmentInputError(InputDataError):
    """Arrays handed to `lads.augment` do not fit its contract (columns, label lengths)."""


class IntensityEncodingError(InputDataError):
    """Intensities lie outside the sensor profile's declared encoding."""


class PhysicsError(LadsError):
    """A physics computation was asked for outside its domain of validity."""


class ReaderError(LadsError):
    """A dataset tree or one of its files cannot be read as the reader's format."""


class DatasetNotFoundError(ReaderError):
    """The source root does not hold the layout the reader expects."""


class CorruptItemError(ReaderError):
    """One item's files are truncated, mis-sized, inconsistent or unreadable."""


class StageError(LadsError):
    """A pipeline stage cannot process a frame."""


class BuildError(LadsError):
    """A build cannot start or finish (output inside the source, a conflicting tree, ...)."""


class OutputWriteError(BuildError):
    """Bytes cannot be written to the output: the disk is full, the file system is read-only
    or permission is denied. It stops the whole build (every later write would fail too)."""


class ManifestError(LadsError):
    """A manifest, SHA256SUMS or run.json is missing or inconsistent."""


class VerifyError(LadsError):
    """An output tree does not verify against its source (raised only by the CLI layer)."""


class ModelError(LadsError):
    """Intensity model weights missing, corrupt, or made for another sensor or input."""


class TrainingError(LadsError):
    """An intensity training run cannot start or continue (config, cache or checkpoint)."""


class DiagnoseError(LadsError):
    """Two trees cannot be compared by `lads diagnose` (missing, mismatched or other sensor)."""
