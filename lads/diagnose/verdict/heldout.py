"""What the held-out groups say about a diagnosis: the fitted noise model with its held-out
test, and intensity and dropout metrics of the simulation, the baseline and the final fit."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.stats import wasserstein_distance

from lads.diagnose.config import CONFIG
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.likelihood import Model
from lads.diagnose.fit.model import Fit, fit
from lads.diagnose.selection.compare import compare_on
from lads.diagnose.selection.grouping import Split
from lads.diagnose.selection.select import Z_ACCEPT, Selection
from lads.diagnose.verdict.intervals import interval95
from lads.diagnose.verdict.point_noise import point_noise

NOISE_MIN_SLOPE = CONFIG.verdict.noise_min_slope
# The neighbour-difference slopes (point_noise.py) that matter: shot noise has 1 per ln R
# (-0.5 per ln I); with homoscedastic noise the estimator still reads a small slope (pairs
# that straddle two surfaces, the rounding model), up to about a third on piecewise-planar
# ground, so the bar sits between that and shot noise.
POINT_NOISE_MIN_SLOPE = CONFIG.verdict.point_noise_min_slope


def noise_model(
    final: Fit,
    d: Design,
    boot: npt.NDArray[np.float64],
    sel: Selection,
    weights: npt.NDArray[np.float64],
    split: Split,
) -> dict[str, Any]:
    """The fitted noise of ln I: sigma and its slopes in ln R and ln I_sim, with CIs.

    "heteroscedastic" is a held-out verdict like any effect's: against the selected model
    refitted with constant sigma on the same training rows, the directional score toward the
    sloped sigma must exceed Z_ACCEPT cluster SEs on the held-out groups, and a slope must be
    large enough to matter (NOISE_MIN_SLOPE). A bootstrap z of the slope alone would miss
    real slopes: the object-level spread every surface shares dilutes the slope of ln
    sigma, not its likelihood gain.
    """
    th = final.theta
    out: dict[str, Any] = {
        "form": "ln sigma = ln_sigma + range_slope (ln R - m_R) + level_slope (ln I_sim - m_I)",
        "sigma_ln_i": float(math.exp(th[1])),
        "range_slope": float(th[2]),
        "level_slope": float(th[3]),
        "return_probability": float(1.0 / (1.0 + math.exp(-th[4]))),
        # Real values stored at a clip below the encoding's maximum are censored (from_table).
        "real_clip_level": d.real_clip,
    }
    if boot.shape[0] >= 5:
        for i, name in ((2, "range_slope"), (3, "level_slope")):
            lo, hi = interval95(boot[:, i])
            out[f"{name}_ci95"] = [float(lo), float(hi)]
    het = sel.fit
    flat = Model(
        list(het.model.effects), het.model.ln_range_ref, het.model.ln_sim_ref, heteroscedastic=False
    )
    start = het.theta.copy()
    start[2:4] = 0.0
    hom = fit(flat, d, weights, start)
    held_out = np.concatenate([split.validation, split.test])
    c = compare_on(het, hom, d.subset(held_out), 1.0, 1.0)
    out["heldout_gain_nats"] = {"delta": c.delta, "se": c.se}
    big = max(abs(th[2]), abs(th[3])) > NOISE_MIN_SLOPE
    out["heldout_gain_nats"]["z"] = c.z
    total = "heteroscedastic" if big and c.z > Z_ACCEPT else "homoscedastic"
    mu = final.predictions(d)[0]
    fit_rows = np.concatenate([split.train, split.validation])
    refs = (final.model.ln_range_ref, final.model.ln_sim_ref)
    out["point_noise"] = point_noise(
        d, mu, fit_rows, split.test, *refs, POINT_NOISE_MIN_SLOPE, Z_ACCEPT
    )
    # Either test may see it: the total sigma a noise that every surface's own reflectance
    # does not swamp, the neighbour differences one that it does (point_noise.py).
    hetero = total == "heteroscedastic" or out["point_noise"]["kind"] == "heteroscedastic"
    out["kind"] = "heteroscedastic" if hetero else "homoscedastic"
    return out


def heldout_metrics(
    d: Design, rows: npt.NDArray[np.int64], baseline: Fit, final: Fit
) -> dict[str, Any]:
    """Metrics on the test groups: the simulation as is, the baseline fit and the final fit."""
    sub = d.subset(rows)
    # Intensity errors on returns stored clear of the quantisation floor and the clip: below
    # it the stored value is an interval, and an error in ln I would measure the rounding.
    ret = sub.fits_intensity & (sub.censor.numpy() == 0)
    y = sub.y.numpy()
    out: dict[str, Any] = {
        "rows": int(len(sub)),
        "groups": int(len(np.unique(sub.group))),
        "intensity_rows": int(ret.sum()),
    }
    out["simulation"] = _intensity_metrics(y[ret], sub.ln_sim.numpy()[ret], None, sub, ret)
    for name, f in (("before", baseline), ("after", final)):
        mu_np, sigma_np, p_np = f.predictions(sub)
        m = _intensity_metrics(y[ret], mu_np[ret], sigma_np[ret], sub, ret)
        if sub.paired:
            obs = sub.returned.numpy().astype(np.float64)
            pc = np.clip(p_np, 1e-9, 1 - 1e-9)
            m["dropout_brier"] = float(np.mean((pc - obs) ** 2))
            m["dropout_log_loss"] = float(-np.mean(obs * np.log(pc) + (1 - obs) * np.log(1 - pc)))
        m["nll"] = float(np.mean(f.row_nll(sub)))
        out[name] = m
    b, a = out["before"], out["after"]
    if b["rmse_ln_i"] and a["rmse_ln_i"] is not None:
        # Share of the baseline's mean squared ln I error that the effects remove.
        out["explained_share"] = float(1.0 - (a["rmse_ln_i"] / b["rmse_ln_i"]) ** 2)
    return out


def _intensity_metrics(
    y: npt.NDArray[np.float64],
    mu: npt.NDArray[np.float64],
    sigma: npt.NDArray[np.float64] | None,
    sub: Design,
    ret: npt.NDArray[np.bool_],
) -> dict[str, Any]:
    err = y - mu
    if y.size == 0:
        return {"rmse_ln_i": None, "mae_ln_i": None, "r2_ln_i": None}
    ss_tot = float(((y - y.mean()) ** 2).sum())
    out: dict[str, Any] = {
        "rmse_ln_i": float(np.sqrt(np.mean(err**2))),
        "mae_ln_i": float(np.mean(np.abs(err))),
        "median_abs_ln_i": float(np.median(np.abs(err))),
        "r2_ln_i": float(1.0 - (err**2).sum() / ss_tot) if ss_tot > 0 else None,
    }
    # Per-class W1 between real ln I and the model's predictive draws (mu + sigma z).
    cls = sub.class_index.numpy()[ret]
    rng = np.random.default_rng(0)
    draws = mu + (sigma if sigma is not None else 0.0) * rng.standard_normal(mu.size)
    w1: dict[str, float] = {}
    for ci, name in enumerate(sub.class_names):
        sel = cls == ci
        if sel.sum() >= 30:
            w1[name] = float(wasserstein_distance(y[sel], draws[sel]))
    if not w1 and y.size >= 30:
        w1["all"] = float(wasserstein_distance(y, draws))
    out["w1_ln_i_by_class"] = w1
    return out
