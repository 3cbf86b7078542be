"""Point noise of ln I from differences between neighbouring returns (docs/diagnose.md E11).

The likelihood's sigma is the spread of every residual about the fitted model: point noise
(shot noise, speckle) plus the reflectance every surface has and the simulation does not
know. The surface part is the larger (M2 draws sigma 0.2-0.4 per object against a point
noise of 0.05-0.2), so a point noise that quadruples from 5 to 40 m moves the total sigma by
a few per cent and its slope is rarely significant in the likelihood. Two returns next to each other
on one ring share the surface, its reflectance and every smooth term of the model; their
difference holds the point noise of both (the von Neumann successive-difference estimate),
plus both values' rounding.

Model: d_ij = e_i - e_j, e = ln(I_real + h) - mu (the fitted model), Student t (NU degrees
of freedom: a pair that straddles two surfaces is a heavy tail, not noise) with scale^2
s_i^2 + s_j^2 + q_i + q_j, ln s = ln_sigma + range_slope (ln R - m_R) + level_slope
(ln I_sim - m_I) (the likelihood's own noise form), q the variance of ln(x + h) over each
stored value's rounding interval, real and simulated. Slopes get cluster-robust (sandwich)
CIs over the groups; "heteroscedastic" is a held-out verdict on the test groups' pairs.
Where the rounding is as large as the noise (0.03 at 10 steps above 0) their sum is no t:
the level slope then reads ~0.1 on constant noise (tests/unit/test_diagnose_point_noise.py).
Pure computation on a `Design`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.optimize
from scipy.special import gammaln

from lads.diagnose.config import CONFIG
from lads.diagnose.fit.design import Design, evenly_spaced
from lads.diagnose.fit.from_table import sim_log_variance
from lads.diagnose.selection.compare import by_rows
from lads.diagnose.where.binning import RANGE_EDGES_M

NU = CONFIG.point_noise.nu
# The t(NU) scale that maximises the likelihood of N(0, 1) data (solves E[(NU + 1) x^2 /
# (NU s^2 + x^2)] = 1): a Gaussian point noise of sigma is read as a scale of 0.831 sigma.
GAUSS_SCALE = 0.8310
MAX_GAP_SPACINGS = CONFIG.point_noise.max_gap_spacings
MAX_DR_SHARE = CONFIG.point_noise.max_dr_share
MAX_DR_M = CONFIG.point_noise.max_dr_m
MIN_PAIRS = CONFIG.point_noise.min_pairs
MIN_BIN_PAIRS = CONFIG.point_noise.min_bin_pairs
FIT_PAIRS = CONFIG.point_noise.fit_pairs
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Pairs:
    """Neighbouring returns of one design, (P,) each.

    Attributes:
        i, j: int64 rows of the design. d: float64 difference of their residuals.
        q: float64 summed rounding variance of the four stored values. group: int64, row i's.
    """

    i: npt.NDArray[np.int64]
    j: npt.NDArray[np.int64]
    d: npt.NDArray[np.float64]
    q: npt.NDArray[np.float64]
    group: npt.NDArray[np.int64]

    def take(self, k: npt.NDArray[np.int64]) -> Pairs:
        return Pairs(self.i[k], self.j[k], self.d[k], self.q[k], self.group[k])

    def __len__(self) -> int:
        return len(self.d)


def neighbour_pairs(d: Design, mu: npt.NDArray[np.float64]) -> Pairs:
    """Pairs of consecutive returns on one ring of one scan, both fitted as exact values,
    of one class and group, within MAX_GAP_SPACINGS azimuth spacings and at nearly the same
    range (`mu`: (N,) the model's ln(I_real + h))."""
    ok = np.flatnonzero(d.fits_intensity & (d.censor.numpy() == 0))
    if len(ok) < 2:
        return _empty()
    scan, ring = d.scan.numpy(), d.ring.numpy()
    az, r = d.azimuth_deg.numpy(), d.range_m.numpy()
    rows = ok[np.lexsort((az[ok], ring[ok], scan[ok]))]
    a, b = rows[:-1], rows[1:]
    same = (scan[a] == scan[b]) & (ring[a] == ring[b])
    gap = az[b] - az[a]
    positive = gap[same & (gap > 0)]
    if positive.size == 0:
        return _empty()
    # The median gap is the sensor's azimuth spacing: most consecutive returns are adjacent.
    spacing = float(np.median(positive))
    keep = same & (gap > 0) & (gap <= MAX_GAP_SPACINGS * spacing)
    keep &= d.class_index.numpy()[a] == d.class_index.numpy()[b]
    keep &= d.group[a] == d.group[b]
    keep &= np.abs(r[a] - r[b]) <= MAX_DR_SHARE * np.minimum(r[a], r[b]) + MAX_DR_M
    a, b = a[keep], b[keep]
    y = d.y.numpy()
    e = y - mu
    i_real = np.exp(y) - d.half_step
    q_real = sim_log_variance(i_real, d.step, d.half_step)
    sim_var = d.sim_var.numpy()
    q = q_real[a] + q_real[b] + sim_var[a] + sim_var[b]
    return Pairs(a, b, e[a] - e[b], q, d.group[a])


def _empty() -> Pairs:
    z = np.zeros(0, dtype=np.int64)
    return Pairs(z, z, np.zeros(0), np.zeros(0), z)


@dataclass(frozen=True)
class _Regressors:
    """(P, 3) regressors (1, ln R - m_R, ln I_sim - m_I) of each pair's two rows."""

    xi: npt.NDArray[np.float64]
    xj: npt.NDArray[np.float64]

    @classmethod
    def of(cls, d: Design, p: Pairs, ln_range_ref: float, ln_sim_ref: float) -> _Regressors:
        lr, ls = d.ln_range.numpy(), d.ln_sim.numpy()

        def x(rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
            return np.column_stack(
                [np.ones(len(rows)), lr[rows] - ln_range_ref, ls[rows] - ln_sim_ref]
            )

        return cls(x(p.i), x(p.j))


def _nll_terms(
    theta: npt.NDArray[np.float64], x: _Regressors, p: Pairs
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(P,) Student-t NLL of each pair and (P, 3) its gradient in theta."""
    vi = np.exp(2.0 * (x.xi @ theta))
    vj = np.exp(2.0 * (x.xj @ theta))
    s2 = vi + vj + p.q
    u = p.d * p.d / s2
    nll = 0.5 * np.log(s2) + 0.5 * (NU + 1.0) * np.log1p(u / NU)
    nll += gammaln(0.5 * NU) - gammaln(0.5 * (NU + 1.0)) + 0.5 * math.log(NU * math.pi)
    # d nll / d s2, then d s2 / d theta = 2 v_i x_i + 2 v_j x_j.
    ds2 = 0.5 / s2 * (1.0 - (NU + 1.0) * u / (NU + u))
    grad = ds2[:, None] * (2.0 * vi[:, None] * x.xi + 2.0 * vj[:, None] * x.xj)
    return nll, grad


def _fit(
    x: _Regressors, p: Pairs, start: npt.NDArray[np.float64], free: npt.NDArray[np.bool_]
) -> npt.NDArray[np.float64]:
    """theta minimising the mean pair NLL over the `free` coordinates (the rest stay 0)."""

    def loss(v: npt.NDArray[np.float64]) -> tuple[float, npt.NDArray[np.float64]]:
        th = np.zeros(3)
        th[free] = v
        nll, grad = _nll_terms(th, x, p)
        return float(nll.mean()), grad.mean(axis=0)[free]

    res = scipy.optimize.minimize(loss, start[free], jac=True, method="L-BFGS-B")
    out = np.zeros(3)
    out[free] = res.x
    return out


def _sandwich(theta: npt.NDArray[np.float64], x: _Regressors, p: Pairs) -> npt.NDArray[np.float64]:
    """(3, 3) cluster-robust covariance of theta over the pairs' groups."""
    _, grad = _nll_terms(theta, x, p)
    n = len(p)
    hess = np.zeros((3, 3))
    for k in range(3):
        # Central differences of the analytic gradient: three parameters, six evaluations.
        step = np.zeros(3)
        step[k] = 1e-5
        up = _nll_terms(theta + step, x, p)[1].mean(axis=0)
        down = _nll_terms(theta - step, x, p)[1].mean(axis=0)
        hess[:, k] = (up - down) / 2e-5
    hess = 0.5 * (hess + hess.T)
    _, inv = np.unique(p.group, return_inverse=True)
    k_groups = int(inv.max()) + 1
    scores = (
        np.stack(
            [np.bincount(inv, weights=grad[:, c], minlength=k_groups) for c in range(3)], axis=1
        )
        / n
    )
    meat = scores.T @ scores * k_groups / max(k_groups - 1, 1)
    h_inv = np.linalg.pinv(hess)
    return h_inv @ meat @ h_inv


def point_noise(
    d: Design,
    mu: npt.NDArray[np.float64],
    fit_rows: npt.NDArray[np.int64],
    test_rows: npt.NDArray[np.int64],
    ln_range_ref: float,
    ln_sim_ref: float,
    min_slope: float,
    z_accept: float,
) -> dict[str, Any]:
    """The point noise of ln I (module docstring), fitted on pairs within `fit_rows` and
    judged on pairs within `test_rows` (numpy row indices of `d`; `mu` (N,) the final
    model's ln(I_real + h)).

    Returns a dict: pairs, t_scale_ln_i (the t scale at the reference range and level) and
    sigma_ln_i_if_gaussian (the sigma of Gaussian noise with that scale),
    range_slope, level_slope with ci95, heldout_gain_nats {delta, se, z} of the sloped over
    the constant scale on the test pairs, and kind: "heteroscedastic" when that gain's z
    exceeds `z_accept` and a slope exceeds `min_slope`, "homoscedastic" otherwise, or
    "undetermined" with a reason when too few pairs exist; and by_range (`by_range`)."""
    pairs = neighbour_pairs(d, mu)
    train = _pairs_within(pairs, fit_rows, len(d))
    test = _pairs_within(pairs, test_rows, len(d))
    out: dict[str, Any] = {
        "method": "differences of neighbouring returns on one ring and surface, Student t "
        f"(nu = {NU:g}), rounding variance removed",
        "pairs": int(len(train)),
        "test_pairs": int(len(test)),
    }
    if len(train) < MIN_PAIRS or len(test) < MIN_PAIRS:
        out["kind"] = "undetermined"
        out["reason"] = (
            f"{len(train)} fitting and {len(test)} test neighbour pairs; at least "
            f"{MIN_PAIRS} of each are needed"
        )
        return out
    train = train.take(evenly_spaced(len(train), FIT_PAIRS))
    x = _Regressors.of(d, train, ln_range_ref, ln_sim_ref)
    sloped, flat = _fit_laws(x, train)
    out.update(_law_fields(sloped, _sandwich(sloped, x, train)))
    xt = _Regressors.of(d, test, ln_range_ref, ln_sim_ref)
    gain = _nll_terms(flat, xt, test)[0] - _nll_terms(sloped, xt, test)[0]
    c = by_rows(gain, gain, test.group)
    out["heldout_gain_nats"] = {"delta": c.delta, "se": c.se, "z": c.z}
    big = max(abs(sloped[1]), abs(sloped[2])) > min_slope
    out["kind"] = "heteroscedastic" if big and c.z > z_accept else "homoscedastic"
    out["by_range"] = by_range(d, train, sloped, ln_range_ref, ln_sim_ref)
    return out


def _pairs_within(pairs: Pairs, rows: npt.NDArray[np.int64], n_rows: int) -> Pairs:
    """The pairs whose two rows are both among `rows` (numpy row indices of a design of
    `n_rows` rows)."""
    inside = np.zeros(n_rows, dtype=bool)
    inside[rows] = True
    return pairs.take(np.flatnonzero(inside[pairs.i] & inside[pairs.j]))


def _fit_laws(
    x: _Regressors, train: Pairs
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(3,) theta of the sloped law and of the constant scale (slopes held at 0), both fitted
    on the training pairs from the robust scale of their differences."""
    # MAD / 0.6745 of d is sqrt(2) sigma.
    mad = float(np.median(np.abs(train.d))) / 0.6745
    start = np.array([math.log(max(mad, 1e-3) / math.sqrt(2.0)), 0.0, 0.0])
    sloped = _fit(x, train, start, np.ones(3, dtype=bool))
    flat = _fit(x, train, start, np.array([True, False, False]))
    return sloped, flat


def _law_fields(sloped: npt.NDArray[np.float64], cov: npt.NDArray[np.float64]) -> dict[str, Any]:
    """The report's fields of the sloped law `sloped` (3,) with covariance `cov` (3, 3): its
    t scale at the reference range and level, that scale's Gaussian sigma, and both slopes
    with their ci95."""
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    out: dict[str, Any] = {
        "t_scale_ln_i": float(math.exp(sloped[0])),
        "sigma_ln_i_if_gaussian": float(math.exp(sloped[0]) / GAUSS_SCALE),
    }
    for k, name in ((1, "range_slope"), (2, "level_slope")):
        out[name] = float(sloped[k])
        out[f"{name}_ci95"] = [float(sloped[k] - Z95 * se[k]), float(sloped[k] + Z95 * se[k])]
    return out


def by_range(
    d: Design, p: Pairs, theta: npt.NDArray[np.float64], ln_range_ref: float, ln_sim_ref: float
) -> list[dict[str, float | None]]:
    """Per range bin (binning.RANGE_EDGES_M) with >= MIN_BIN_PAIRS pairs: the model-free
    point noise sqrt(MAD(d)^2 / 2 - median(q) / 2) (None when not positive), MAD = median
    |d| / 0.6745 (the Gaussian sigma of the differences, robust to pairs that straddle two
    surfaces),
    beside the fitted law's Gaussian sigma at the bin's median ln R and ln I_sim: the check
    a reader can do by eye (figures.point_noise)."""
    r = np.sqrt(d.range_m.numpy()[p.i] * d.range_m.numpy()[p.j])
    ln_r = 0.5 * (d.ln_range.numpy()[p.i] + d.ln_range.numpy()[p.j])
    ln_s = 0.5 * (d.ln_sim.numpy()[p.i] + d.ln_sim.numpy()[p.j])
    edges = np.asarray(RANGE_EDGES_M)
    index = np.searchsorted(edges, r, side="right") - 1
    out = []
    for k in range(len(edges) - 1):
        sel = index == k
        n = int(sel.sum())
        if n < MIN_BIN_PAIRS:
            continue
        mad = float(np.median(np.abs(p.d[sel]))) / 0.6745
        var = 0.5 * mad * mad - 0.5 * float(np.median(p.q[sel]))
        ln_scale = (
            theta[0]
            + theta[1] * (float(np.median(ln_r[sel])) - ln_range_ref)
            + theta[2] * (float(np.median(ln_s[sel])) - ln_sim_ref)
        )
        out.append(
            {
                "range_lo_m": float(edges[k]),
                "range_hi_m": float(edges[k + 1]),
                "range_m": float(np.median(r[sel])),
                "pairs": n,
                # None: the rounding is as large as the differences (integer
                # counts a few steps above 0, most neighbours stored alike).
                "sigma_ln_i": math.sqrt(var) if var > 0.0 else None,
                "fitted_sigma_ln_i": math.exp(ln_scale) / GAUSS_SCALE,
            }
        )
    return out
