"""Plain JSON types from nested results (reports, benchmark documents)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def json_types(value: Any, *, significant: int | None = None) -> Any:
    """`value` with JSON types only: dict keys as str, tuples and arrays as lists, numpy
    scalars unwrapped, NaN and inf as None, other objects (paths) as str; floats rounded to
    `significant` digits when given (stable, diffable result files)."""
    if isinstance(value, dict):
        return {str(k): json_types(v, significant=significant) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_types(v, significant=significant) for v in value]
    if isinstance(value, np.ndarray):
        return json_types(value.tolist(), significant=significant)
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        x = float(value)
        if not math.isfinite(x):
            return None
        return float(f"{x:.{significant}g}") if significant is not None else x
    if value is None or isinstance(value, str):
        return value
    return str(value)
