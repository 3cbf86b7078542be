"""Which scans of a sequence make one frame's window (docs/transfer.md §3).

A frame's window is the span of `neighbours + 1` consecutive scan numbers around it (half
before, half after; the extra one after when `neighbours` is odd), moved inside the
sequence at its ends so that the first and last frames get as many neighbours as the
others. Scans of the span that the tree does not hold are simply absent: a tree of
isolated frames transfers each frame from its own scan.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

from lads.errors import ConfigError

T = TypeVar("T")
# (item) -> (sequence key, scan number): a reader's `scan_position`.
Position = Callable[[T], tuple[str, int]]

# Neighbouring scans of a frame's window by default: ten, as in lidar_transfer's and
# LiDomAug's accumulated scenes (1 s at 10 Hz), enough to close the target's new occlusions.
DEFAULT_NEIGHBOURS = 10
MAX_NEIGHBOURS = 200


def check_neighbours(neighbours: object, where: str) -> int:
    """`neighbours` as an int in 0..MAX_NEIGHBOURS, else ConfigError naming `where`."""
    if isinstance(neighbours, bool) or not isinstance(neighbours, int):
        raise ConfigError(
            f"{where}: neighbours must be a whole number of scans, got {neighbours!r}."
        )
    if not 0 <= neighbours <= MAX_NEIGHBOURS:
        raise ConfigError(
            f"{where}: neighbours is {neighbours}; expected 0..{MAX_NEIGHBOURS} scans "
            "(0: each frame from its own scan alone)."
        )
    return neighbours


def window_of(
    items: Sequence[T], centre: T, neighbours: int, position: Position[T]
) -> tuple[list[T], int]:
    """The scans of `centre`'s window, in scan order, and the centre's index among them.

    Args:
        items: every scan the tree holds (any order; other sequences are ignored).
        centre: the frame to transfer (one of `items`).
        neighbours: how many neighbouring scan numbers the window spans besides the centre.
        position: the reader's (sequence, scan number) of an item.
    """
    seq, number = position(centre)
    same = {n: it for it in items for s, n in [position(it)] if s == seq}
    same[number] = centre
    first_held, last_held = min(same), max(same)
    before = neighbours // 2
    start = number - before
    # Shift the span inside the scans the sequence holds, as far as it fits.
    start = min(start, last_held - neighbours)
    start = max(start, first_held)
    numbers = [n for n in range(start, start + neighbours + 1) if n in same]
    return [same[n] for n in numbers], numbers.index(number)
