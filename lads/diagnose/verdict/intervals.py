"""Bootstrap intervals of fitted parameters (docs/diagnose.md §5.6)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt


def ci95(
    params: dict[str, Any], samples: list[dict[str, Any]], floor: dict[str, float] | None = None
) -> dict[str, Any]:
    """95 % percentile intervals of `samples`; a scalar's interval spans at least
    `floor[name]` either side of its estimate (a resolution the bootstrap cannot see)."""
    out: dict[str, Any] = {}
    floor = floor or {}
    for name, value in params.items():
        vals = [s[name] for s in samples if name in s]
        if not vals:
            out[name] = None
            continue
        if isinstance(value, list):
            arr = np.array([v for v in vals if len(v) == len(value)], dtype=np.float64)
            if arr.size == 0:
                out[name] = None
                continue
            lo, hi = interval95(arr)
            out[name] = [[float(a), float(b)] for a, b in zip(lo, hi, strict=True)]
        else:
            lo, hi = interval95(np.asarray(vals, dtype=np.float64))
            pad = floor.get(name, 0.0)
            out[name] = [float(min(lo, value - pad)), float(max(hi, value + pad))]
    return out


def interval95(samples: npt.NDArray[np.float64]) -> tuple[Any, Any]:
    """The 2.5 and 97.5 % points of (B, ...) bootstrap `samples` along axis 0, read at
    order-statistic positions q (B + 1) (Hyndman & Fan type 6).

    A further draw from the same distribution falls between the k-th smallest and k-th
    largest of B draws with probability (B + 1 - 2k) / (B + 1). numpy's default positions
    q (B - 1) + 1 put the bounds near the 2nd order statistics at B = 40: an interval that
    covers 90 %, not 95 %, however good the bootstrap. Type 6 puts them at k = 1.025."""
    lo, hi = np.percentile(samples, [2.5, 97.5], axis=0, method="weibull")
    return lo, hi


def sample_arrays(params: dict[str, Any], samples: Any) -> dict[str, npt.NDArray[np.float64]]:
    """(B,) bootstrap values of each scalar parameter of `params` (per-ring lists left out)."""
    out = {}
    for name, value in params.items():
        if not isinstance(value, list):
            out[name] = np.array([s[name] for s in samples], dtype=np.float64)
    return out
