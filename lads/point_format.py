"""Which point record a sensor transfer writes: `writer.point_format` of a pipeline.

- "source" (the default): each scan in the source format's record (its columns; intensity
  in the target's encoding, a `ring` column holding the target's channel).
- "target": each scan in the target sensor's native record, at the source's relative path:
  the columns of the reader of the dataset format its profile names (`native_format`), e.g.
  nuScenes' x, y, z, intensity, ring for the HDL-32E.

Format knowledge stays in the readers: a profile names a reader, the reader gives the
columns (`columns`) and says whether its format's own tooling fixes the record
(`record_fixed_by`). docs/transfer.md §3.
"""

from __future__ import annotations

from dataclasses import dataclass

from lads.errors import PointFormatError

POINT_FORMATS = ("source", "target")
DEFAULT_POINT_FORMAT = "source"


@dataclass(frozen=True, slots=True)
class PointRecord:
    """A point record: the dataset format it comes from and its float32 columns in file order.

    Attributes:
        format: a reader name of `lads.readers.READERS`, e.g. "nuscenes".
        columns: the columns of a scan file, e.g. ("x", "y", "z", "intensity", "ring").
    """

    format: str
    columns: tuple[str, ...]


def native_record(profile: str) -> PointRecord:
    """The native record of a sensor profile: its `native_format` reader's columns.

    Args:
        profile: a shipped profile name ("hdl32e") or a profile YAML path.

    Raises:
        PointFormatError: the profile names no native format, or one that is no reader.
    """
    from lads.readers import READERS, reader_class
    from lads.sensors.profile import load_profile

    native = load_profile(profile).native_format
    if native is None or native not in READERS:
        what = "names no native_format" if native is None else f"names native_format {native!r}"
        raise PointFormatError(
            f"sensor profile {profile!r} {what}; --point-format target writes the target's "
            f"native record, so add `native_format: <reader>` (one of {', '.join(READERS)}) "
            "to the profile, or build with --point-format source."
        )
    return PointRecord(native, tuple(reader_class(native).columns))


def target_record(source: str, target: str) -> PointRecord:
    """The record a build of `source` to `target` writes with point_format "target", checked
    against what the source's layout can hold. Called before any frame is built.

    Args:
        source: the source reader name (`--source`).
        target: the sensor stage's target profile.

    Raises:
        PointFormatError: the target has no native record, or the source format's own
            tooling reads every scan file with its own columns (`record_fixed_by`) and the
            target's record has others; the message says what to use instead.
    """
    from lads.readers import reader_class

    record = native_record(target)
    reader = reader_class(source)
    fixed = reader.record_fixed_by
    if fixed and record.columns != tuple(reader.columns):
        raise PointFormatError(
            f"--point-format target: the native record of {target} is {record.format}'s "
            f"({_columns(record.columns)}), but a {source} tree's scans are read by {fixed}; "
            f"files of {len(record.columns)} columns there would be misread. Build with "
            f"--point-format source (writer.point_format: source): the {target} scan in the "
            f"{source} record ({_columns(reader.columns)}), intensity in the {target} "
            "encoding, a ring column holding its channel."
        )
    return record


def check_point_format(value: object, target: str | None, variant: str) -> None:
    """Check `writer.point_format` of pipeline `variant`, whose sensor stage (if any) has
    the profile `target`: a point format name, and "target" only with a target that has a
    native record.

    Raises:
        PointFormatError: naming the setting, what is expected and what to do.
    """
    if value not in POINT_FORMATS:
        raise PointFormatError(
            f"writer.point_format is {value!r}; expected one of {', '.join(POINT_FORMATS)} "
            "(the source's point record or the target sensor's native one, docs/transfer.md §3)."
        )
    if value == DEFAULT_POINT_FORMAT:
        return
    if target is None:
        raise no_sensor_stage(variant, f"writer.point_format {value!r}")
    native_record(target)


def no_sensor_stage(variant: str, what: str) -> PointFormatError:
    """The error for a point format asked of pipeline `variant`, which has no sensor stage."""
    return PointFormatError(
        f"{what} does not apply to pipeline '{variant}': without a sensor stage its scans keep "
        "the source's sensor and point record. Drop it, or build a sensor-<profile> variant "
        "(docs/transfer.md §3)."
    )


def _columns(columns: tuple[str, ...]) -> str:
    return f"{len(columns)} float32 columns: {', '.join(columns)}"


__all__ = [
    "DEFAULT_POINT_FORMAT",
    "POINT_FORMATS",
    "PointRecord",
    "check_point_format",
    "native_record",
    "no_sensor_stage",
    "target_record",
]
