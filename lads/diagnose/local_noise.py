"""Does the point noise of ln I grow with range? A test on neighbouring returns of one surface.

The residual of a return (ln I_real minus the fitted prediction) is surface-level spread (a
surface brighter or darker than its class) plus point noise. Fitted as one sigma(R), the
surface spread every return shares hides a point noise that grows several-fold with range
(K19: sigma_pt 0.05 at 10 m, 0.2 at 40 m, under a surface spread of 0.3). The difference
of two neighbouring returns of the same surface cancels the surface term: its variance is
2 sigma_pt(R)^2 plus both values' known rounding variances. ln sigma_pt = a + b (ln R - m)
is fitted to those differences by Fisher scoring, and b's SE is a sandwich clustered by
the design's spatial groups (neighbours share a group, groups are independent).

Neighbours: consecutive returns of one ring of one scan, within NEIGHBOUR_MAX_DEG in
azimuth, NEIGHBOUR_MAX_DR_M in range and of the same class, both stored clear of the
quantisation floor (censor 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.diagnose.design import Design, sim_log_variance

NEIGHBOUR_MAX_DEG = 0.5  # ~3 azimuth steps of an HDL-64E, 1.5 of an HDL-32E
NEIGHBOUR_MAX_DR_M = 0.3
MIN_PAIRS = 200
MAX_ITER = 50


@dataclass(frozen=True)
class LocalNoise:
    """ln sigma_pt = ln_sigma + range_slope (ln R - ln_range_ref) from neighbour pairs."""

    pairs: int
    groups: int
    ln_sigma: float
    range_slope: float
    range_slope_se: float

    @property
    def z(self) -> float:
        return self.range_slope / max(self.range_slope_se, 1e-12)


def neighbour_pairs(d: Design, rows: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """(P, 2) design rows of neighbouring returns of one surface among `rows`."""
    ok = (d.returned & d.sim_ok & (d.censor == 0)).numpy()
    rows = rows[ok[rows]]
    scan, ring = d.scan.numpy()[rows], d.ring.numpy()[rows]
    az = d.azimuth_deg.numpy()[rows]
    order = rows[np.lexsort((az, ring, scan))]
    a, b = order[:-1], order[1:]
    same = (d.scan.numpy()[a] == d.scan.numpy()[b]) & (d.ring.numpy()[a] == d.ring.numpy()[b])
    same &= d.class_index.numpy()[a] == d.class_index.numpy()[b]
    close = np.abs(d.azimuth_deg.numpy()[b] - d.azimuth_deg.numpy()[a]) <= NEIGHBOUR_MAX_DEG
    r = d.range_m.numpy()
    close &= np.abs(r[b] - r[a]) <= NEIGHBOUR_MAX_DR_M
    keep = same & close
    # Pairs that share a return are not independent: of a chain of pairs, every other one.
    start = keep & ~np.r_[False, keep[:-1]]
    first = np.flatnonzero(start)[np.maximum(np.cumsum(start) - 1, 0)] if start.any() else 0
    keep &= (np.arange(keep.size) - first) % 2 == 0
    return np.column_stack([a[keep], b[keep]])


def local_noise(
    d: Design, mu: npt.NDArray[np.float64], rows: npt.NDArray[np.int64], ln_range_ref: float
) -> LocalNoise | None:
    """Fit the point noise's range slope on neighbour pairs among `rows`; None when fewer
    than MIN_PAIRS pairs or two groups are found.

    Args:
        d: the design; mu: (N,) the fitted prediction of ln(I_real + h) for every row.
        rows: design rows to use (held-out groups).
        ln_range_ref: the centre m of ln R in the slope's parametrisation.
    """
    pairs = neighbour_pairs(d, np.asarray(rows, dtype=np.int64))
    if len(pairs) < MIN_PAIRS:
        return None
    y = d.y.numpy()
    h, step = d.half_step, d.step
    resid = y - mu
    diff2 = (resid[pairs[:, 0]] - resid[pairs[:, 1]]) ** 2
    real_var = sim_log_variance(np.exp(y) - h, step, h)
    known = real_var[pairs].sum(axis=1) + d.sim_var.numpy()[pairs].sum(axis=1)
    x = 0.5 * d.ln_range.numpy()[pairs].sum(axis=1) - ln_range_ref
    groups = d.group[pairs[:, 0]]
    if len(np.unique(groups)) < 2:
        return None
    design = np.column_stack([np.ones(len(x)), x])
    theta = np.array([0.5 * math.log(max(np.mean(np.maximum(diff2 - known, 1e-8)) / 2, 1e-8)),
                      0.0])  # fmt: skip
    for _ in range(MAX_ITER):
        grad, info = _score(theta, design, diff2, known)
        move = np.linalg.solve(info, grad)
        theta = theta - move
        if np.max(np.abs(move)) < 1e-8:
            break
    noise = 2.0 * np.exp(2.0 * design @ theta)
    v = noise + known
    w = noise / v
    per_pair = ((1.0 - diff2 / v) * w)[:, None] * design
    _, inverse = np.unique(groups, return_inverse=True)
    by_group = np.zeros((inverse.max() + 1, 2))
    np.add.at(by_group, inverse, per_pair)
    info = (2.0 * w**2)[:, None, None] * design[:, :, None] * design[:, None, :]
    bread = np.linalg.inv(info.sum(axis=0))
    cov = bread @ (by_group.T @ by_group) @ bread
    return LocalNoise(pairs=len(pairs), groups=int(by_group.shape[0]), ln_sigma=float(theta[0]),
                      range_slope=float(theta[1]),
                      range_slope_se=float(math.sqrt(max(cov[1, 1], 0.0))))  # fmt: skip


def _score(
    theta: npt.NDArray[np.float64],
    design: npt.NDArray[np.float64],
    diff2: npt.NDArray[np.float64],
    known: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Gradient and Fisher information of the NLL of diff ~ N(0, 2 sigma^2 + known)."""
    noise = 2.0 * np.exp(2.0 * design @ theta)
    v = noise + known
    w = noise / v
    grad = ((1.0 - diff2 / v) * w) @ design
    info = (design * (2.0 * w**2)[:, None]).T @ design
    return grad, info
