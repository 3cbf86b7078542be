"""Designs from beam tables: the rows a fit reads, censored where the stored value is an
interval, for paired tables, unpaired pseudo-pairs and predictions (docs/diagnose.md §5.1).

Only rows the simulation returned enter a paired fit (a beam the simulation did not fire
cannot be mis-simulated; real-only rows are reported as extra returns). Unpaired tables are
turned into pseudo-pairs: each real return is compared with the mean ln I of the simulated
returns in the same feature cell (class x ring x range bin x cos bin), so only
feature-conditional differences are ever fitted.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import scipy.optimize
import torch
from scipy.special import ndtr, ndtri

from lads.diagnose.config import CONFIG
from lads.diagnose.data.table import BeamTable
from lads.diagnose.fit.design import Design, evenly_spaced

COS_FLOOR = CONFIG.design.cos_floor
EDGE_NEAR_BEAMS = CONFIG.design.edge_near_beams
LOW_STEPS = CONFIG.design.low_steps
ZERO_FIT_STEPS = CONFIG.design.zero_fit_steps
ZERO_FIT_MIN_ROWS = CONFIG.design.zero_fit_min_rows
ZERO_QUANTILES = CONFIG.design.zero_quantiles
TOBIT_MAX_ROWS = CONFIG.design.tobit_max_rows
# A clip below the encoding's maximum (C9's i_max: firmware saturation, a gain stage) shows
# as an atom at the top of the real values: the largest stored value holding CLIP_RATIO
# times the rows of the step below it and CLIP_MIN_SHARE of all returns. Noise spreads a
# smooth tail, whose top values hold fewer rows than the ones below them.
CLIP_RATIO = CONFIG.design.clip_ratio
CLIP_MIN_SHARE = CONFIG.design.clip_min_share
CLIP_MIN_ROWS = CONFIG.design.clip_min_rows


def paired_design(table: BeamTable) -> Design:
    """Design of a paired table: the rows with a simulated return stored below the clip.

    A simulated value stored at the encoding's maximum is only a lower bound of what the
    simulation meant; used as exact it biases every fitted slope (a near-range clip reads as
    a flatter range law), so those rows are left out."""
    rows = np.flatnonzero(table.ret_sim & np.isfinite(table.i_sim) & ~_sim_clipped(table))
    t = table.take(rows)
    i_real = np.nan_to_num(t.i_real, nan=0.0).astype(np.float64)
    h, step = t.sensor.half_step, t.sensor.step
    i_sim = t.i_sim.astype(np.float64)
    sim_mean, sim_var = _sim_log_moments(i_sim, step, h)
    ln_sim = np.log(i_sim + h)
    zero = i_sim < 0.5 * step
    low = i_sim < (ZERO_FIT_STEPS + 0.5) * step
    sim_mean[low] = _low_power(t, i_sim, low, step, h)
    return _design(
        t, rows, i_real, t.ret_real.copy(), ln_sim, True, sim_var, ~zero, sim_mean - ln_sim
    )


def saturated_rows(table: BeamTable) -> npt.NDArray[np.int64]:
    """Rows of a paired table whose simulated return is stored at the encoding's maximum
    (left out of `paired_design`, predicted by `prediction_design`)."""
    return np.flatnonzero(table.ret_sim & np.isfinite(table.i_sim) & _sim_clipped(table))


def _sim_clipped(table: BeamTable) -> npt.NDArray[np.bool_]:
    return table.i_sim > table.sensor.max_value - 0.5 * table.sensor.step


def prediction_design(table: BeamTable, rows: npt.NDArray[np.int64], like: Design) -> Design:
    """Design of simulated returns `rows` of `table` to predict from, not to fit on.

    Its real columns are empty (no row is returned). The simulated value is taken as
    stored: one at the encoding's maximum is a lower bound of what the simulation meant, so
    for the catalogue's laws (monotone in ln I_sim) the prediction is a lower bound too,
    which the writer clips at the maximum again. Left at the maximum instead, saturated
    beams would keep none of the fitted effects.
    Classes, per-scan levels (C10) and the real clip are `like`'s when both designs hold
    the same scans (paired), so a fitted per-class or per-scan term means the same rows;
    unpaired, the simulated scans are other scans and get their own levels."""
    t = table.take(rows)
    h, step = t.sensor.half_step, t.sensor.step
    i_sim = t.i_sim.astype(np.float64)
    sim_mean, sim_var = _sim_log_moments(i_sim, step, h)
    ln_sim = np.log(i_sim + h)
    n = len(rows)
    return _design(
        t,
        rows,
        np.zeros(n),
        np.zeros(n, dtype=bool),
        ln_sim,
        like.paired,
        sim_var,
        i_sim >= 0.5 * step,
        sim_mean - ln_sim,
        like=like,
    )


def clip_level(i_real: npt.ArrayLike, step: float, max_value: float) -> float | None:
    """The stored value the real intensities are clipped at below `max_value`, or None.

    Args:
        i_real: (N,) real intensities of the returned beams, stored units.
        step, max_value: the encoding's quantisation step and maximum, stored units.
    """
    values = np.asarray(i_real, dtype=np.float64)
    if values.size == 0:
        return None
    top = float(values.max())
    if top > max_value - 0.5 * step or top < LOW_STEPS * step:
        return None
    at_top = int(np.count_nonzero(values > top - 0.5 * step))
    below = int(np.count_nonzero(np.abs(values - (top - step)) < 0.5 * step))
    if at_top < max(CLIP_RATIO * below, CLIP_MIN_SHARE * values.size, CLIP_MIN_ROWS):
        return None
    return top


def _low_power(
    t: BeamTable, i_sim: npt.NDArray[np.float64], low: npt.NDArray[np.bool_], step: float, h: float
) -> npt.NDArray[np.float64]:
    """E[ln(x + h)] of the values stored within ZERO_FIT_STEPS steps of 0, x their power
    imputed from their geometry within their rounding interval.

    A stored 0 hides anything below half a step, and which part of that interval a beam
    came from differs by class and range (a dark, far class sits near 0): a detection
    threshold works exactly there, and in the first steps above. The simulation's own law
    (ln I on ln R, ln cos, class) is fitted by censored (Tobit) regression: the low rows
    enter as "below ZERO_FIT_STEPS + 1/2 steps". Least squares on the rows above alone
    selects, far out, only the beams that came out bright, flattens the range slope and
    imputed the stored 0s too bright on average (tests/unit/test_diagnose_dropout.py), which
    biases fitted detection thresholds (ln tau) high.
    With too few rows above, the interval's uniform mean is kept."""
    uniform = _sim_log_moments(i_sim[low], step, h)[0]
    x = _geometry_columns(t)
    clear = ~low & (i_sim > 0)
    if clear.sum() < ZERO_FIT_MIN_ROWS or not low.any():
        return uniform
    cut = math.log((ZERO_FIT_STEPS + 0.5) * step)
    coef, spread = _tobit(x, np.log(np.maximum(i_sim, 0.5 * step)), ~clear, cut)
    # E[ln(x + h)] with ln x ~ N(prediction, spread^2) truncated to the rounding interval
    # (its quantiles at evenly spaced levels): a point prediction clipped to the interval
    # would pile the extremes onto its ends.
    pred = x[low] @ coef
    k = np.round(i_sim[low] / step)
    lo = np.where(k > 0, np.log(np.maximum(k - 0.5, 1e-9) * step), -np.inf)
    p_lo = ndtr((lo - pred) / spread)
    p_hi = ndtr((np.log((k + 0.5) * step) - pred) / spread)
    levels = (np.arange(ZERO_QUANTILES) + 0.5) / ZERO_QUANTILES
    p = p_lo[:, None] + (p_hi - p_lo)[:, None] * levels
    ln_x = pred[:, None] + spread * ndtri(np.clip(p, 1e-300, 1.0 - 1e-16))
    return np.mean(np.log(np.exp(ln_x) + h), axis=1)


def _tobit(
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    censored: npt.NDArray[np.bool_],
    cut: float,
) -> tuple[npt.NDArray[np.float64], float]:
    """(coef, sigma) of y = x coef + N(0, sigma^2) with y known only to be < cut where
    `censored`: maximum likelihood from the least-squares start (scipy L-BFGS-B, torch
    gradients). At most TOBIT_MAX_ROWS evenly spaced rows are used."""
    take = evenly_spaced(len(y), TOBIT_MAX_ROWS)
    x, y, censored = x[take], y[take], censored[take]
    start = np.linalg.lstsq(x[~censored], y[~censored], rcond=None)[0]
    spread0 = max(float(np.std(y[~censored] - x[~censored] @ start)), 1e-3)
    xt, yt = torch.as_tensor(x), torch.as_tensor(y)
    cen = torch.as_tensor(censored)

    def loss(v: npt.NDArray[np.float64]) -> tuple[float, npt.NDArray[np.float64]]:
        th = torch.as_tensor(v).requires_grad_(True)
        sigma = torch.exp(th[-1])
        pred = xt @ th[:-1]
        z = (yt - pred) / sigma
        below = torch.special.log_ndtr((cut - pred) / sigma)
        nll = torch.where(cen, -below, 0.5 * z**2 + th[-1]).mean()
        nll.backward()
        return float(nll.detach()), th.grad.numpy().copy()  # type: ignore[union-attr]

    res = scipy.optimize.minimize(
        loss, np.r_[start, math.log(spread0)], jac=True, method="L-BFGS-B"
    )
    return res.x[:-1], max(float(math.exp(res.x[-1])), 1e-3)


def _geometry_columns(t: BeamTable) -> npt.NDArray[np.float64]:
    """(N, K) regressors of the simulation's law: 1, ln R, ln cos, normal flag, class dummies."""
    cos = np.clip(t.cos_incidence.astype(np.float64), COS_FLOOR, 1.0)
    ok = t.normal_ok.astype(np.float64)
    cols = [np.ones(len(t)), np.log(np.maximum(t.range_m, 1e-3)), ok * np.log(cos), ok]
    cols += [(t.class_id == c).astype(np.float64) for c in np.unique(t.class_id)[1:]]
    return np.column_stack(cols)


def sim_log_variance(i_sim: npt.ArrayLike, step: float, h: float) -> npt.NDArray[np.float64]:
    """(N,) variance of ln(x + h), x uniform on the stored value's rounding interval."""
    return _sim_log_moments(i_sim, step, h)[1]


def _sim_log_moments(
    i_sim: npt.ArrayLike, step: float, h: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(mean, variance) of ln(x + h), x uniform on the stored value's rounding interval.

    A simulated tree is stored in the sensor's encoding, so a value of k steps stands for
    anything within half a step of it: its ln is uncertain by Var (errors in variables),
    large a few steps from 0. The mean differs from ln(i_sim + h) by < 0.02 from one step on
    (and the stored value may be exact), so only the variance is used. Closed forms:
    integral of ln u = u ln u - u, of ln^2 u = u (ln^2 u - 2 ln u + 2).
    """
    x = np.asarray(i_sim, dtype=np.float64)
    a = np.maximum(x - 0.5 * step, 0.0) + h
    b = x + 0.5 * step + h
    la, lb = np.log(a), np.log(b)
    width = b - a
    mean = ((b * lb - b) - (a * la - a)) / width
    second = (b * (lb * lb - 2.0 * lb + 2.0) - a * (la * la - 2.0 * la + 2.0)) / width
    return mean, np.maximum(second - mean * mean, 0.0)


def unpaired_design(sim: BeamTable, real: BeamTable, *, min_cell_rows: int = 5) -> Design:
    """Pseudo-paired design of two unpaired tables of the same sensor.

    Every real return whose feature cell holds at least `min_cell_rows` simulated returns gets
    ln_sim = the mean ln(i_sim + h) of that cell; the rest are left out.
    """
    key_sim = _cell_key(sim)
    key_real = _cell_key(real)
    ln_sim_rows = np.log(sim.i_sim.astype(np.float64) + sim.sensor.half_step)
    uniq, inverse = np.unique(key_sim, return_inverse=True)
    counts = np.bincount(inverse, minlength=len(uniq))
    means = np.bincount(inverse, weights=ln_sim_rows, minlength=len(uniq)) / np.maximum(counts, 1)
    pos = np.searchsorted(uniq, key_real)
    pos = np.clip(pos, 0, len(uniq) - 1)
    found = (uniq[pos] == key_real) & (counts[pos] >= min_cell_rows)
    rows = np.flatnonzero(found & real.ret_real)
    t = real.take(rows)
    i_real = t.i_real.astype(np.float64)
    # A cell mean over >= min_cell_rows values: its rounding error is averaged away.
    return _design(
        t,
        rows,
        i_real,
        np.ones(len(rows), dtype=bool),
        means[pos[rows]],
        False,
        np.zeros(len(rows)),
        np.ones(len(rows), dtype=bool),
        np.zeros(len(rows)),
    )


def _cell_key(t: BeamTable) -> npt.NDArray[np.int64]:
    edges = np.array([2.0, 3.5, 5.0, 7.5, 10.0, 15.0, 20.0, 30.0, 40.0, 60.0, 80.0])
    rbin = np.searchsorted(edges, t.range_m).astype(np.int64)
    cbin = np.minimum((t.cos_incidence * 10).astype(np.int64), 9)
    cls = t.class_id.astype(np.int64) + 1
    return ((cls * 256 + t.ring.astype(np.int64)) * 16 + rbin) * 16 + cbin


def _design(
    t: BeamTable,
    rows: npt.NDArray[np.int64],
    i_real: npt.NDArray[np.float64],
    returned: npt.NDArray[np.bool_],
    ln_sim: npt.NDArray[np.float64],
    paired: bool,
    sim_var: npt.NDArray[np.float64],
    sim_ok: npt.NDArray[np.bool_],
    sim_shift: npt.NDArray[np.float64],
    like: Design | None = None,
) -> Design:
    clip, y, y_lo, y_hi, censor = _observations(t, i_real, returned, like)
    classes, class_names, class_index = _class_indices(t, like)
    cos = np.clip(t.cos_incidence.astype(np.float64), 0.0, 1.0)
    ln_cos = np.where(t.normal_ok, np.log(np.maximum(cos, COS_FLOOR)), 0.0)
    scans = t.scan.astype(np.int64)
    n_scans = len(t.scans)
    scan_mean = _scan_means(scans, n_scans, ln_sim, like)

    def f64(a: npt.ArrayLike) -> torch.Tensor:
        return torch.as_tensor(np.asarray(a, dtype=np.float64))

    return Design(
        y=f64(y),
        y_lo=f64(y_lo),
        y_hi=f64(y_hi),
        censor=torch.as_tensor(censor),
        ln_sim=f64(ln_sim),
        sim_var=f64(sim_var),
        sim_shift=f64(sim_shift),
        sim_ok=torch.as_tensor(sim_ok, dtype=torch.bool),
        returned=torch.as_tensor(returned, dtype=torch.bool),
        ln_range=f64(np.log(np.maximum(t.range_m, 1e-3))),
        range_m=f64(t.range_m),
        cos=f64(cos),
        ln_cos=f64(ln_cos),
        normal_ok=torch.as_tensor(t.normal_ok, dtype=torch.bool),
        ring=torch.as_tensor(t.ring.astype(np.int64)),
        class_index=torch.as_tensor(class_index),
        scan=torch.as_tensor(scans),
        azimuth_deg=f64(t.azimuth_deg),
        edge_beams=f64(t.edge_beams),
        edge_span_beams=f64(t.edge_span_beams),
        is_ground=torch.as_tensor(t.is_ground, dtype=torch.bool),
        scan_ln_mean=f64(scan_mean[scans]),
        group=t.group.astype(np.int64),
        rows=rows.astype(np.int64),
        classes=classes,
        class_names=class_names,
        half_step=t.sensor.half_step,
        full_scale=t.sensor.full_scale,
        max_value=t.sensor.max_value,
        step=t.sensor.step,
        n_rings=t.sensor.n_rings,
        n_scans=n_scans,
        paired=paired,
        real_clip=clip,
        label_set=t.sensor.label_set,
    )


def _observations(
    t: BeamTable,
    i_real: npt.NDArray[np.float64],
    returned: npt.NDArray[np.bool_],
    like: Design | None,
) -> tuple[
    float | None,
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.int64],
]:
    """The real intensity as the likelihood sees it: the clip level (`like`'s, else found in
    the returns), ln(I + h), the bounds of its quantisation interval and the censoring code
    per row (0 none, 1 low, 2 below half a step, 3 at the top)."""
    h, step, top = t.sensor.half_step, t.sensor.step, t.sensor.max_value
    clip = clip_level(i_real[returned], step, top) if like is None else like.real_clip
    if clip is not None:
        top = clip
    y = np.where(returned, np.log(i_real + h), 0.0)
    censor = np.zeros(len(i_real), dtype=np.int64)
    censor[returned & (i_real < LOW_STEPS * step)] = 1
    censor[returned & (i_real < 0.5 * step)] = 2
    censor[returned & (i_real > top - 0.5 * step)] = 3
    y_lo = np.log(np.maximum(i_real - 0.5 * step, 0.0) + h)
    y_hi = np.log(i_real + 0.5 * step + h)
    return clip, y, y_lo, y_hi, censor


def _class_indices(
    t: BeamTable, like: Design | None
) -> tuple[tuple[int, ...], tuple[str, ...], npt.NDArray[np.int64]]:
    """The classes (`like`'s, else the table's labelled ones), their names, and each row's
    index among them (-1: none)."""
    if like is None:
        classes = tuple(int(c) for c in np.unique(t.class_id[t.class_id >= 0]))
        class_names = tuple(t.class_names.get(c, str(c)) for c in classes)
    else:
        classes, class_names = like.classes, like.class_names
    lookup = {c: i for i, c in enumerate(classes)}
    class_index = np.array([lookup.get(int(c), -1) for c in t.class_id], dtype=np.int64)
    return classes, class_names, class_index


def _scan_means(
    scans: npt.NDArray[np.int64],
    n_scans: int,
    ln_sim: npt.NDArray[np.float64],
    like: Design | None,
) -> npt.NDArray[np.float64]:
    """(n_scans,) mean ln I_sim per scan, centred on the count-weighted mean (a paired
    `like`'s own means where it has them, 0 elsewhere)."""
    if like is not None and like.paired:
        scan_mean = np.zeros(n_scans)
        scan_mean[like.scan.numpy()] = like.scan_ln_mean.numpy()
        return scan_mean
    sums = np.bincount(scans, weights=ln_sim, minlength=n_scans)
    counts = np.maximum(np.bincount(scans, minlength=n_scans), 1)
    scan_mean = sums / counts
    return scan_mean - np.average(scan_mean, weights=counts)
