"""The fog echo in front of a hard target: the peak of the soft (volume) return, tabulated
per extinction (the formula and its derivation: `lads.physics.fog`'s module docstring,
docs/physics.md §7)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from lads.errors import ConfigError

if TYPE_CHECKING:  # FogParams' module imports this one
    from lads.physics.fog import FogParams


@dataclass(frozen=True, slots=True)
class SoftReturnTable:
    """Peak of P_soft(r; r0) / (pi beta_pi) for one extinction, on a grid of target ranges.

    Attributes:
        target_range_m: (K,) float64 grid of r0, m, from R1 to R2 + L.
        peak_range_m: (K,) float64 raw peak range r* (pulse-start timing), m.
        peak_unit: (K,) float64 peak value divided by pi beta_pi, 1/m (times beta_pi and pi:
            normalised power).
        relative_curvature_per_m2: (K,) float64 |P''(r*)| / P(r*), 1/m^2.
    """

    target_range_m: npt.NDArray[np.float64]
    peak_range_m: npt.NDArray[np.float64]
    peak_unit: npt.NDArray[np.float64]
    relative_curvature_per_m2: npt.NDArray[np.float64]


@functools.lru_cache(maxsize=64)
def soft_return_table(extinction_per_m: float, params: FogParams) -> SoftReturnTable:
    """Tabulate the fog-return peak for target ranges R1 .. R2 + L (exact beyond: constant).

    Midpoint rule on cells of `table_step_m` in s; target ranges sit on cell edges, so the
    Heaviside cut is exact there and a cumulative sum over cells gives every r0 at once.
    The peak over r is refined by a parabola through the best grid point and its neighbours.
    """
    h, length = params.table_step_m, params.pulse_length_m
    r1, r2 = params.overlap_start_m, params.overlap_full_m
    if r1 is None or r2 is None:
        raise ConfigError("soft_return_table needs FogParams.resolved_for(sensor) first.")
    n_cells = math.ceil((r2 + length - r1) / h)
    edges = r1 + h * np.arange(n_cells + 1)
    centre = edges[:-1] + 0.5 * h
    if r2 > r1:
        overlap = np.clip((centre - r1) / (r2 - r1), 0.0, 1.0)
    else:
        overlap = (centre > r1).astype(np.float64)
    g = overlap * np.exp(-2.0 * extinction_per_m * centre) / centre**2 * h
    r = r1 + h * np.arange(math.ceil((r2 + 2 * length - r1) / h) + 2)
    lag = r[:, None] - centre[None, :]
    kernel = np.where((lag >= 0) & (lag <= length), np.sin(np.pi * lag / length) ** 2, 0.0)
    power = np.cumsum(kernel * g[None, :], axis=1)  # power[i, k]: P(r_i; r0 = edges[k + 1])
    cols = np.arange(n_cells)
    i = np.clip(np.argmax(power, axis=0), 1, r.size - 2)
    left, mid, right = power[i - 1, cols], power[i, cols], power[i + 1, cols]
    second = left - 2 * mid + right
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(second < 0, 0.5 * (left - right) / second, 0.0)
    shift = np.clip(shift, -1.0, 1.0)
    peak = mid - 0.25 * (left - right) * shift
    curvature = np.where(peak > 0, -second / h**2 / np.where(peak > 0, peak, 1.0), 0.0)
    table = SoftReturnTable(
        target_range_m=edges,
        peak_range_m=np.concatenate(([r[0] + 0.5 * length], r[i] + shift * h)),
        peak_unit=np.concatenate(([0.0], peak)),
        relative_curvature_per_m2=np.concatenate(([curvature[0]], curvature)),
    )
    for arr in (table.target_range_m, table.peak_range_m, table.peak_unit):
        arr.flags.writeable = False
    table.relative_curvature_per_m2.flags.writeable = False
    return table


def _lookup(
    values: npt.NDArray[np.float64], r0: npt.NDArray[np.float64], table: SoftReturnTable
) -> npt.NDArray[np.float64]:
    # Beyond the grid the peak is the r0 = inf one: np.interp holds the last value there.
    return np.interp(r0, table.target_range_m, values)


def soft_return_peak(
    target_range_m: npt.ArrayLike,
    extinction_per_m: float,
    backscatter_per_m_sr: float,
    params: FogParams,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Peak of the fog return in front of targets at r0 (module docstring formula).

    Args:
        target_range_m: (N,) target ranges r0, m.
        extinction_per_m: alpha, 1/m.
        backscatter_per_m_sr: beta_pi, 1/(m sr).
        params: the fog parameters.

    Returns:
        peak_range_m: (N,) float64 raw peak range r* (pulse-start timing, before the
            c tau_H / 2 report shift), m; r0 < R1 (no fog in front) gives r0.
        peak_power: (N,) float64 normalised peak power (reflectivity / m^2); 0 for r0 <= R1.
        relative_curvature_per_m2: (N,) float64 |P''| / P at the peak, 1/m^2.
    """
    r0 = np.asarray(target_range_m, dtype=np.float64)
    table = soft_return_table(float(extinction_per_m), params)
    r1 = params.overlap_start_m
    if r1 is None:  # soft_return_table has refused unresolved params already
        raise ConfigError("soft_return_peak needs FogParams.resolved_for(sensor) first.")
    power = np.pi * backscatter_per_m_sr * _lookup(table.peak_unit, r0, table)
    peak_range = np.where(r0 < r1, r0, _lookup(table.peak_range_m, r0, table))
    power[r0 < r1] = 0.0
    return peak_range, power, _lookup(table.relative_curvature_per_m2, r0, table)
