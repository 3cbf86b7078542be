"""RADIATE: Velodyne HDL-32E scans as CSV text, one line per point.

Layout (docs/formats.md §4), relative to the reader root (the folder that holds the sequence
folders, or one sequence folder itself):

    <seq>/velo_lidar/NNNNNN.csv   text, one line `x,y,z,intensity,ring` per point, "\\n" line
                                  ends: x, y, z in m, intensity 0-255 and ring 0-31 (0 = lowest
                                  beam, -30.67 deg) as integers
    <seq>/velo_lidar.txt          `Frame: NNNNNN Time: <unix s.ns>` per frame, copied
    <seq>/meta.json               sequence metadata, copied

No point labels. Number format: every value is printf `%.5g` of the stored number (five
significant digits, trailing zeros and a bare trailing point dropped, integers as integers),
as MATLAB's `csvwrite`/`dlmwrite` default writes. Parsing to float32 and printing again with
`%.5g` reproduces all 307,135 values of the three shared fog frames byte for byte, so encode
uses that rule. It cannot reproduce CRLF line ends, a missing final newline, leading `+`
signs or other spellings of the same number (none occur in the real files); points a stage
moves are rounded to five significant digits, the format's own precision (1 mm at 10-99 m).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from lads.errors import CorruptItemError, DatasetNotFoundError
from lads.frame import Frame, Item
from lads.readers.base import (
    EncodedFile,
    check_finite,
    entries_matching,
    normalize_sequences,
    present,
    select_sequences,
    unreadable_reason,
)

_FIELDS = 5
_SCAN_DIR = "velo_lidar"


class RadiateReader:
    """Reader and encoder of RADIATE `velo_lidar/*.csv` scans.

    Args:
        root: the folder that holds `<seq>/velo_lidar/`, or a sequence folder that holds
            `velo_lidar/` itself (relpaths then start with `velo_lidar/`).
        sequences: sequence folder names to restrict to; None for all (ignored when root is
            a sequence folder).

    Frames: columns ("x", "y", "z", "intensity", "ring"); points (N, 5) float32: xyz in m,
    intensity 0-255, ring 0-31 (both integer-valued); labels None.
    """

    name = "radiate"
    sensor = "hdl32e"
    particle_label = 0  # unused: RADIATE has no point labels
    label_set = None
    columns: tuple[str, ...] = ("x", "y", "z", "intensity", "ring")
    record_fixed_by: str | None = (
        "RADIATE's velo_lidar CSV, one line of 5 fields (x, y, z, intensity, ring) per point"
    )

    def __init__(self, root: str | Path, *, sequences: Iterable[str] | None = None):
        self.root = Path(root)
        self.sequences = normalize_sequences(sequences)

    def __repr__(self) -> str:
        return f"RadiateReader({str(self.root)!r}, sequences={self.sequences!r})"

    def _expected(self) -> str:
        return (
            f"the RADIATE layout <seq>/velo_lidar/NNNNNN.csv under {self.root}; pass the folder "
            "that holds the sequence folders (or one sequence folder)"
        )

    def _prefixes(self) -> list[str]:
        """'' when root is a sequence folder, else '<seq>/' of each selected sequence."""
        if (self.root / _SCAN_DIR).is_dir():
            return [""]
        if not self.root.is_dir():
            raise DatasetNotFoundError(f"{self.root}: no such folder; expected {self._expected()}.")
        found = [d.name for d in self.root.iterdir() if (d / _SCAN_DIR).is_dir()]
        return [
            f"{s}/" for s in select_sequences(found, self.sequences, self.root, self._expected())
        ]

    def items(self) -> list[Item]:
        """Every `velo_lidar/*.csv` of the selected sequences, sorted by relpath; no labels."""
        items = [
            Item(self.name, f"{prefix}{_SCAN_DIR}/{scan.name}")
            for prefix in self._prefixes()
            for scan in entries_matching(self.root / prefix / _SCAN_DIR, ".csv")
        ]
        if not items:
            raise DatasetNotFoundError(f"{self.root}: no scans found; expected {self._expected()}.")
        return sorted(items, key=lambda it: it.relpath)

    def copied_files(self) -> list[str]:
        """`<seq>/velo_lidar.txt` and `<seq>/meta.json` where present."""
        out = []
        for prefix in self._prefixes():
            for name in ("velo_lidar.txt", "meta.json"):
                if present(self.root / prefix / name):
                    out.append(f"{prefix}{name}")
        return sorted(out)

    def read(self, item: Item) -> Frame:
        """Parse the CSV into (N, 5) float32 points; N = number of lines."""
        path = self.root / item.relpath
        try:
            text = path.read_bytes().decode("ascii")
        except OSError as exc:
            raise CorruptItemError(
                f"{path}: cannot read RADIATE scan: {unreadable_reason(path, exc)}. Check that "
                "the file exists and is readable, or re-extract it."
            ) from exc
        except UnicodeDecodeError as exc:
            raise CorruptItemError(
                f"{path}: not ASCII text ({exc}); expected lines `x,y,z,intensity,ring`. "
                "Re-extract the file."
            ) from exc
        lines = text.split("\n")
        while lines and not lines[-1].strip():  # blank lines at the end are no points
            lines.pop()
        bad = next((i for i, ln in enumerate(lines) if ln.count(",") != _FIELDS - 1), None)
        if bad is not None:
            raise CorruptItemError(
                f"{path}: line {bad + 1} is {lines[bad][:80]!r}; expected {_FIELDS} "
                "comma-separated numbers `x,y,z,intensity,ring` per line. The file is truncated "
                "or not a RADIATE velo_lidar scan: re-extract it."
            )
        try:
            values = np.array(",".join(lines).split(",") if lines else [], dtype=np.float64)
        except ValueError as exc:
            raise CorruptItemError(_not_numbers(path, lines, exc)) from exc
        points = values.astype(np.float32).reshape(-1, _FIELDS)
        check_finite(points, path, self.columns)
        return Frame.from_source(item, self.sensor, self.columns, points, None)

    def encode(self, frame: Frame) -> list[EncodedFile]:
        """One text file: `%.5g` of each value, ',' between values, '\\n' after each line."""
        from lads.errors import InvalidPointsError

        points = np.asarray(frame.points)
        rel = frame.item.relpath
        if points.ndim != 2 or points.shape[1] != _FIELDS:
            raise InvalidPointsError(
                f"{frame.item.item_id}: points have shape {points.shape}, expected (M, 5) "
                f"x, y, z, intensity, ring for {rel}."
            )
        if not np.isfinite(points).all():
            raise InvalidPointsError(
                f"{frame.item.item_id}: points hold NaN or inf; {rel} would be unreadable."
            )
        n = points.shape[0]
        values = points.astype(np.float64).ravel().tolist()
        text = ("%.5g,%.5g,%.5g,%.5g,%.5g\n" * n) % tuple(values)
        return [EncodedFile(rel, "scan", text.encode("ascii"), n, 0)]


def _not_numbers(path: Path, lines: list[str], exc: ValueError) -> str:
    """The message for a scan with a value that is not a number, naming its line: a header
    line (RADIATE's scans have none) or a damaged one."""
    for k, line in enumerate(lines):
        try:
            [float(v) for v in line.split(",")]
        except ValueError:
            if k == 0:
                return (
                    f"{path}: line 1 is {line[:80]!r}, a header; RADIATE velo_lidar scans hold "
                    "only numbers `x,y,z,intensity,ring`: delete that line."
                )
            return (
                f"{path}: line {k + 1} is {line[:80]!r}; expected only numbers "
                "`x,y,z,intensity,ring` per line. The file is corrupt: re-extract it."
            )
    return f"{path}: {exc}; expected only numbers `x,y,z,intensity,ring` per line."
