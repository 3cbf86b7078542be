"""The fit of a model (`lads.diagnose.fit.likelihood`) to a design: scipy's L-BFGS-B on the
box bounds with exact gradients from torch autograd, from several starts; which parameters sit
at a bound that binds; and the model's predictions.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.optimize
import torch

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.base import Effect
from lads.diagnose.fit.design import Design
from lads.diagnose.fit.likelihood import BASE_NAMES, Model, RowTerms, log_detect, nll_from_terms

MAX_ITER = CONFIG.fit.max_iter
FTOL = CONFIG.fit.ftol
# is 1e-7 nats, four orders below the smallest gain an effect is accepted for (select.py
# MIN_GAIN_NATS), and it halves the iterations of the slow per-ring fits
# L-BFGS memory (scipy default 10). 64 ring gains or 20 class scales each touch a few % of
# the rows, so the curvature spans orders of magnitude, and with 10 pairs such fits often
# ran into MAX_ITER. A longer memory reaches the same optimum in fewer iterations where the
# likelihood is well curved; where it is flat (e.g. an encoding fitted on one frame) the
# optimum reached can differ.
MAXCOR = CONFIG.fit.maxcor
BOUND_TOLERANCE = CONFIG.fit.bound_tolerance
# A bound binds when moving 5 % of the range inward costs more than 1e-6 nats per row (the
# fits converge to ~1e-7; the smallest gain an effect is accepted for is 2e-3).
BOUND_NUDGE = CONFIG.fit.bound_nudge
FLAT_LOSS = CONFIG.fit.flat_loss


@dataclass
class Fit:
    """A fitted model: its parameter vector and training loss (mean NLL per row)."""

    model: Model
    theta: npt.NDArray[np.float64]
    loss: float
    converged: bool

    def effect_params(self, label: str) -> npt.NDArray[np.float64]:
        for e, sl in zip(self.model.effects, self.model.slices(), strict=True):
            if e.label == label:
                return self.theta[sl]
        raise KeyError(label)

    def at_bound(self) -> list[str]:
        """Labels of effects with a scalar parameter at (within 1 % of) a bound."""
        out = []
        for e, sl in zip(self.model.effects, self.model.slices(), strict=True):
            th = self.theta[sl]
            width = e.upper - e.lower
            finite = np.isfinite(width) & e.scalar
            near = (np.abs(th - e.lower) < BOUND_TOLERANCE * width) | (
                np.abs(e.upper - th) < BOUND_TOLERANCE * width
            )
            if np.any(near & finite):
                out.append(e.label)
        return out

    def binding_bounds(self, d: Design, weights: npt.NDArray[np.float64]) -> list[str]:
        """`at_bound` labels whose bound binds: moving the parameter inward by
        BOUND_NUDGE of its range raises the training loss by more than FLAT_LOSS.

        A parameter the data do not inform sits wherever the optimiser left it, often on a
        bound: a wet road whose every return beyond theta_c is lost leaves no surviving row
        to show the film's darkening f, and f = 0 then says nothing about the effect."""
        flagged = self.at_bound()
        if not flagged:
            return []
        loss = self._loss_function(d, weights)
        here = loss(self.theta)
        out = []
        for e, sl in zip(self.model.effects, self.model.slices(), strict=True):
            if e.label not in flagged:
                continue
            th, width = self.theta[sl], e.upper - e.lower
            for j in np.flatnonzero(e.scalar & np.isfinite(width)):
                at_low = abs(th[j] - e.lower[j]) < BOUND_TOLERANCE * width[j]
                at_high = abs(e.upper[j] - th[j]) < BOUND_TOLERANCE * width[j]
                if not (at_low or at_high):
                    continue
                inward = (1.0 if at_low else -1.0) * BOUND_NUDGE * width[j]
                if loss(self._moved(e, sl.start + j, j, inward)) - here > FLAT_LOSS:
                    out.append(e.label)
                    break
        return out

    def _moved(self, e: Effect, index: int, j: int, step: float) -> npt.NDArray[np.float64]:
        """theta with parameter `index` (the `j`-th of effect `e`) moved by `step`, in bounds."""
        x = self.theta.copy()
        x[index] = np.clip(x[index] + step, e.lower[j], e.upper[j])
        return x

    def _loss_function(
        self, d: Design, weights: npt.NDArray[np.float64]
    ) -> Callable[[npt.NDArray[np.float64]], float]:
        """`training_objective` of numpy theta, without gradients."""
        training_loss = training_objective(self.model, d, weights)

        def loss(x: npt.NDArray[np.float64]) -> float:
            with torch.no_grad():
                return float(training_loss(torch.as_tensor(x, dtype=torch.float64)))

        return loss

    def flat_parameters(self, d: Design, weights: npt.NDArray[np.float64]) -> dict[str, list[str]]:
        """{label: names} of scalar parameters the data do not inform: moving one by
        BOUND_NUDGE of its range either way (within bounds) changes the training loss by
        less than FLAT_LOSS. Their bootstrap CI would only echo the start of the refits."""
        loss = self._loss_function(d, weights)
        here = loss(self.theta)
        out: dict[str, list[str]] = {}
        for e, sl in zip(self.model.effects, self.model.slices(), strict=True):
            width = e.upper - e.lower
            for j in np.flatnonzero(e.scalar & np.isfinite(width)):
                changes = [
                    abs(loss(self._moved(e, sl.start + j, j, sign * BOUND_NUDGE * width[j])) - here)
                    for sign in (1.0, -1.0)
                ]
                if max(changes) < FLAT_LOSS:
                    out.setdefault(e.label, []).append(e.names[j])
        return out

    def predictions(self, d: Design) -> tuple[npt.NDArray[np.float64], ...]:
        """(N,) predicted ln(I_real + h), its sigma and P(return) of every row of `d`."""
        with torch.no_grad():
            mu, sigma, log_surv, thr = self.model.predict(torch.as_tensor(self.theta), d)
            p_ret = torch.exp(log_surv)
            if thr is not None:
                p_ret = p_ret * torch.exp(log_detect(thr, mu, sigma, d)[0])
        return mu.numpy(), sigma.numpy(), p_ret.numpy()

    def row_nll(self, d: Design) -> npt.NDArray[np.float64]:
        with torch.no_grad():
            return self.model.nll_rows(torch.as_tensor(self.theta), d).numpy()

    def row_terms(self, d: Design) -> RowTerms:
        with torch.no_grad():
            return self.model.row_terms(torch.as_tensor(self.theta), d)


def directional_gain(start: RowTerms, end: RowTerms, d: Design) -> npt.NDArray[np.float64]:
    """(N,) rate at which each row's NLL falls as its likelihood terms move from `start`
    (the incumbent's) toward `end` (the candidate's): -d nll_i / d lambda at lambda = 0, in
    nats per unit step.

    The score of the held-out test (select.py): the direction is fixed on the training rows,
    so on held-out rows its mean is 0 when the incumbent is right, and it is first order in
    the effect, where the held-out NLL gain is second order (it subtracts the new fit's own
    noise): for an effect of size t the gain's z is about half this score's."""
    step = torch.zeros(len(d), dtype=torch.float64, requires_grad=True)
    nll_from_terms(start.toward(end, step), d).sum().backward()
    return -step.grad.numpy()  # type: ignore[union-attr]


def initial_base(d: Design, rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
    """Baseline start: median residual gain, its spread, no slopes, the return rate."""
    ret = d.fits_intensity[rows]
    r = (d.y.numpy() - d.ln_sim.numpy())[rows][ret]
    gain = float(np.median(r)) if r.size else 0.0
    spread = float(np.std(r)) if r.size > 1 else 1.0
    rate = float(np.clip(ret.mean() if ret.size else 0.99, 0.01, 0.999))
    return np.array([gain, math.log(max(spread, 0.01)), 0.0, 0.0, math.log(rate / (1 - rate))])


def training_objective(
    model: Model, d: Design, weights: npt.NDArray[np.float64]
) -> Callable[[torch.Tensor], torch.Tensor]:
    """The training loss (weighted mean NLL over the rows with weight > 0, plus penalties)
    as a function of theta (a (P,) float64 tensor)."""
    use = np.flatnonzero(weights > 0)
    sub = d.rows_subset(use)
    w = torch.as_tensor(weights[use], dtype=torch.float64)
    total = float(w.sum())

    def loss(theta: torch.Tensor) -> torch.Tensor:
        return (model.nll_rows(theta, sub) * w).sum() / total + model.penalty(theta)

    return loss


def fit(
    model: Model,
    d: Design,
    weights: npt.NDArray[np.float64],
    start: npt.NDArray[np.float64],
    *,
    max_iter: int = MAX_ITER,
) -> Fit:
    """Minimise the weighted mean NLL plus penalties from `start` within the bounds.

    Args:
        model: the effects to fit.
        d: the design (all rows; rows with weight 0 do not count).
        weights: (N,) row weights (0/1 for a split, bootstrap multiplicities).
        start: (P,) initial vector in natural units.
    """
    lower, upper = model.bounds()
    x0 = np.clip(start, lower, upper)
    training_loss = training_objective(model, d, weights)

    def objective(x: npt.NDArray[np.float64]) -> tuple[float, npt.NDArray[np.float64]]:
        theta = torch.as_tensor(x, dtype=torch.float64).requires_grad_(True)
        loss = training_loss(theta)
        loss.backward()
        grad = theta.grad.numpy().copy()  # type: ignore[union-attr]
        value = float(loss.detach())
        if not math.isfinite(value) or not np.all(np.isfinite(grad)):
            return 1e10, np.zeros_like(x)
        return value, grad

    bounds = [
        (None if not math.isfinite(lo) else lo, None if not math.isfinite(hi) else hi)
        for lo, hi in zip(lower, upper, strict=True)
    ]
    options = {"maxiter": max_iter, "ftol": FTOL, "maxcor": MAXCOR}
    res = scipy.optimize.minimize(
        objective, x0, jac=True, method="L-BFGS-B", bounds=bounds, options=options
    )
    value, _ = objective(res.x)
    return Fit(model, res.x, value, bool(res.success))


def start_vectors(
    model: Model, base: npt.NDArray[np.float64], previous: Fit | None
) -> list[npt.NDArray[np.float64]]:
    """Initial vectors: the previous fit's values for shared effects, each new effect's starts."""
    known: dict[str, npt.NDArray[np.float64]] = {}
    head = base
    if previous is not None:
        head = previous.theta[: len(BASE_NAMES)]
        for e, sl in zip(previous.model.effects, previous.model.slices(), strict=True):
            known[e.label] = previous.theta[sl]
    options: list[list[npt.NDArray[np.float64]]] = []
    for e in model.effects:
        options.append([known[e.label]] if e.label in known else e.starts)
    vectors = [np.concatenate([head] + [o[0] for o in options])]
    for i, o in enumerate(options):
        for alt in o[1:]:
            parts = [head] + [opt[0] for opt in options]
            parts[i + 1] = alt
            vectors.append(np.concatenate(parts))
    return vectors


def fit_best(
    model: Model,
    d: Design,
    weights: npt.NDArray[np.float64],
    base: npt.NDArray[np.float64],
    previous: Fit | None = None,
) -> Fit:
    """The best of the fits from every start vector."""
    best: Fit | None = None
    for x0 in start_vectors(model, base, previous):
        f = fit(model, d, weights, x0)
        if best is None or f.loss < best.loss:
            best = f
    return best  # type: ignore[return-value]
