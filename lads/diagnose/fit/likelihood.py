"""The joint likelihood of real intensities and returns given the simulation.

For a beam the simulation returned, with mu = the predicted ln(I_real + h):

    mu      = T(ln(I_sim + h) + ln_gain + sum of effect ln-terms)   T: encoding effects, last
    sigma^2 = s_n^2 + Var of ln I_sim within its rounding interval (known, not fitted)
    ln s_n  = ln_sigma + sigma_range_slope (ln R - m_R) + sigma_level_slope (ln I_sim - m_I)
    P(ret)  = sigmoid(return_logit) * prod of effect survival factors
              * Phi((mu - ln_tau) / sqrt(s^2 + lam^2 sigma^2))  with D1 (detection threshold)

A returned beam contributes ln N(y; mu, sigma) + ln P(ret | y), a dropped one ln(1 - P(ret)).
With D1 the detector sees mu + lam (y - mu): lam = 0 is a threshold on the predicted power
(the catalogue's form), lam = 1 censors the returned value itself (Tobit), so an attenuation
is not under-estimated from the survivors alone (docs/diagnose.md §2 item 2). lam is fitted.
Unpaired designs have no dropout information and use the Gaussian part only. The fit is in
`lads.diagnose.fit.model`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import torch

from lads.diagnose.effects.base import Effect
from lads.diagnose.fit.design import CensoredRows, Design

BASE_NAMES: tuple[str, ...] = (
    "ln_gain", "ln_sigma", "sigma_range_slope", "sigma_level_slope", "return_logit",
)  # fmt: skip
# C0 is "free" in docs/diagnose.md; e^±12 still spans any encoding change, and a finite box keeps
# a term that is collinear with the gain (a ring offset summing to a constant) from drifting.
_BASE_LOWER = np.array([-12.0, -6.0, -3.0, -3.0, -12.0])
_BASE_UPPER = np.array([12.0, 3.0, 3.0, 3.0, 12.0])
_HALF_LN_2PI = 0.5 * math.log(2.0 * math.pi)


@dataclass
class Model:
    """Baseline (gain, noise, constant return rate) plus a list of effects."""

    effects: list[Effect]
    ln_range_ref: float
    ln_sim_ref: float
    heteroscedastic: bool = True

    @property
    def names(self) -> list[str]:
        out = list(BASE_NAMES)
        for e in self.effects:
            out += [f"{e.label}.{n}" for n in e.names]
        return out

    @property
    def size(self) -> int:
        return len(BASE_NAMES) + sum(e.size for e in self.effects)

    def bounds(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        lower = [_BASE_LOWER.copy()]
        upper = [_BASE_UPPER.copy()]
        if not self.heteroscedastic:
            lower[0][2:4] = 0.0
            upper[0][2:4] = 0.0
        for e in self.effects:
            lower.append(e.lower)
            upper.append(e.upper)
        return np.concatenate(lower), np.concatenate(upper)

    def slices(self) -> list[slice]:
        out, start = [], len(BASE_NAMES)
        for e in self.effects:
            out.append(slice(start, start + e.size))
            start += e.size
        return out

    @property
    def key(self) -> frozenset[str]:
        """The set of effect labels (a model's identity, whatever the order they came in)."""
        return frozenset(e.label for e in self.effects)

    def with_effect(self, effect: Effect) -> Model:
        return Model(
            self.effects + [effect], self.ln_range_ref, self.ln_sim_ref, self.heteroscedastic
        )

    def without(self, label: str) -> Model:
        kept = [e for e in self.effects if e.label != label]
        return Model(kept, self.ln_range_ref, self.ln_sim_ref, self.heteroscedastic)

    def predict(
        self, theta: torch.Tensor, d: Design
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """(mu, sigma, log P(ret) without D1, D1 (ln_tau, s) or None) per row."""
        mu = d.ln_sim + theta[0]
        log_surv = torch.nn.functional.logsigmoid(theta[4]).expand_as(mu)
        transfers, threshold = [], None
        for e, sl in zip(self.effects, self.slices(), strict=True):
            th = theta[sl]
            if e.ln_term is not None:
                mu = mu + e.ln_term(th, d)
            if e.transfer is not None:
                transfers.append((e, th))
            if e.log_survival is not None:
                log_surv = log_surv + e.log_survival(th, d)
            if e.extra.get("threshold"):
                threshold = th
        for e, th in transfers:
            mu = e.transfer(th, d, mu)  # type: ignore[misc]
        ln_sigma = (
            theta[1]
            + theta[2] * (d.ln_range - self.ln_range_ref)
            + theta[3] * (d.ln_sim - self.ln_sim_ref)
        )
        # The real value's noise plus the simulated value's own rounding (Design.sim_var).
        sigma = torch.sqrt(torch.exp(2.0 * ln_sigma) + d.sim_var)
        return mu, sigma, log_surv, threshold

    def row_terms(self, theta: torch.Tensor, d: Design) -> RowTerms:
        """The per-row quantities the likelihood is a function of (`nll_from_terms`)."""
        mu, sigma, log_surv, threshold = self.predict(theta, d)
        if not d.paired:
            return RowTerms(mu, torch.log(sigma), None, None)
        log_p_ret = log_surv
        ret_extra = torch.zeros_like(mu)
        if threshold is not None:
            marginal, given_y = log_detect(threshold, mu, sigma, d)
            log_p_ret = log_p_ret + marginal
            # Where the intensity does not enter (a simulated 0) the return is scored by its
            # marginal probability: conditioning on y without its density would double-count.
            ret_extra = torch.where(d.sim_ok, given_y, marginal)
        return RowTerms(mu, torch.log(sigma), log_surv + ret_extra, log_p_ret)

    def nll_rows(self, theta: torch.Tensor, d: Design) -> torch.Tensor:
        """(N,) negative log-likelihood of every row."""
        return nll_from_terms(self.row_terms(theta, d), d)

    def penalty(self, theta: torch.Tensor) -> torch.Tensor:
        total = torch.zeros((), dtype=theta.dtype)
        for e, sl in zip(self.effects, self.slices(), strict=True):
            if e.penalty is not None:
                total = total + e.penalty(theta[sl])
        return total


@dataclass(frozen=True)
class RowTerms:
    """(N,) per-row terms of the likelihood: mu and ln sigma of ln(I_real + h); ln P(return
    | y) of a returned row and ln P(return) of any row (None for unpaired designs)."""

    mu: torch.Tensor
    ln_sigma: torch.Tensor
    ln_p_given: torch.Tensor | None
    ln_p_ret: torch.Tensor | None

    def toward(self, other: RowTerms, step: torch.Tensor) -> RowTerms:
        """The terms moved `step` (per row) of the way to `other`'s, each linearly."""

        def mix(a: torch.Tensor | None, b: torch.Tensor | None) -> torch.Tensor | None:
            if a is None or b is None:
                return None
            return a + step * (b - a)

        return RowTerms(
            mix(self.mu, other.mu),  # type: ignore[arg-type]
            mix(self.ln_sigma, other.ln_sigma),  # type: ignore[arg-type]
            mix(self.ln_p_given, other.ln_p_given),
            mix(self.ln_p_ret, other.ln_p_ret),
        )

    def nll(self, d: Design) -> npt.NDArray[np.float64]:
        """(N,) negative log-likelihood of every row (`nll_from_terms`, no gradient)."""
        with torch.no_grad():
            return nll_from_terms(self, d).numpy()

    def half_deviance(self, d: Design) -> npt.NDArray[np.float64]:
        """(N,) NLL above the saturated model's, in nats (half the deviance).

        The saturated model puts mu on the data: a point value keeps its Gaussian normaliser
        ln sigma + ln sqrt(2 pi) (so 0.5 z^2 is left), a quantisation interval of width w
        the probability erf(w / (2 sqrt(2) sigma)) of a centred mu; a stored 0, a clipped
        value and a return or drop can have probability 1. The normaliser moves with the
        noise level (near sigma = 0.4 it is ~0, so the NLL itself can sit near 0), and a
        coarse encoding's intervals cost their own width's probability at any fit: a share
        of the NLL is no measure of misfit, a share of the deviance is (§5.5 step 4)."""
        use = d.returned & d.sim_ok
        with torch.no_grad():
            sigma = torch.exp(self.ln_sigma)
            width = (d.y_hi - d.y_lo).clamp_min(0.0)
            p_interval = torch.special.erf(width / (2.0 * math.sqrt(2.0) * sigma))
            zero = torch.zeros_like(sigma)
            saturated = torch.where(d.censor == 1, -torch.log(p_interval.clamp_min(1e-300)), zero)
            saturated = torch.where(d.censor == 0, self.ln_sigma + _HALF_LN_2PI, saturated)
            saturated = torch.where(use, saturated, zero)
        return self.nll(d) - saturated.numpy()


def nll_from_terms(t: RowTerms, d: Design) -> torch.Tensor:
    """(N,) negative log-likelihood of every row from its terms (`Model.row_terms`)."""
    sigma = torch.exp(t.ln_sigma)
    z = (d.y - t.mu) / sigma
    gauss = 0.5 * z**2 + t.ln_sigma + _HALF_LN_2PI
    c = d.censored
    if c.rows.numel():
        gauss = gauss.index_put((c.rows,), _interval_nll(c, t.mu[c.rows], sigma[c.rows]))
    # A simulated 0 says nothing about the intensity (Design.sim_ok): the return only.
    gauss = torch.where(d.sim_ok, gauss, torch.zeros_like(gauss))
    if t.ln_p_given is None or t.ln_p_ret is None:
        return gauss
    dropped = -torch.log(-torch.expm1(t.ln_p_ret.clamp(max=-1e-12)))
    return torch.where(d.returned, gauss - t.ln_p_given, dropped)


def _threshold_widths(
    threshold: torch.Tensor, sigma: torch.Tensor, d: Design
) -> tuple[torch.Tensor, torch.Tensor]:
    """(conditional, marginal) widths of the D1 threshold comparison.

    The detector compares a latent ln power L = mu + lam (y - mu) + eta with ln_tau, eta
    ~ N(0, s^2). lam = 0 is the catalogue's P(ret) = Phi((mu - ln_tau) / s): the return
    depends on the predicted power only, and the simulated value's rounding (sim_var) blurs
    it. lam = 1 is the Tobit model: the measured value itself is censored, so survivors are
    biased upwards. The fit chooses; the marginal over y ~ N(mu, sigma) adds lam^2 sigma^2.
    """
    s, lam = threshold[1], threshold[2]
    cond2 = s**2 + (1.0 - lam) ** 2 * d.sim_var
    return torch.sqrt(cond2), torch.sqrt(cond2 + lam**2 * sigma**2)


def log_detect(
    threshold: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor, d: Design
) -> tuple[torch.Tensor, torch.Tensor]:
    """(ln P(ret) with y integrated out, ln P(ret | y) of a returned row) of the threshold."""
    conditional, marginal = _threshold_widths(threshold, sigma, d)
    centre = mu + d.sim_shift
    latent = centre + threshold[2] * (d.y - centre)
    return (
        torch.special.log_ndtr((centre - threshold[0]) / marginal),
        torch.special.log_ndtr((latent - threshold[0]) / conditional),
    )


def _interval_nll(c: CensoredRows, mu: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """-ln P(y in its quantisation interval) (censor 1), below y_hi (2) or above y_lo (3),
    of the rows `c`; `mu`, `sigma` (C,) theirs."""
    censor, two = c.censor, c.two
    z_lo = (c.y_lo - mu) / sigma
    z_hi = (c.y_hi - mu) / sigma
    # One-sided rows need one log-CDF, interval rows two: the log-CDF is the costliest op of
    # a fit, so each kind gets only its own (the same values as computing all and masking).
    # A one-sided row is an interval with a = -inf (below y_hi) or b = +inf (above y_lo).
    upper = (z_lo > 0) & ~c.one_sided
    # Phi(b) - Phi(a) loses all digits when both are near 1: use the mirrored tail there.
    b = torch.where(censor == 3, -z_lo, torch.where(upper, -z_lo, z_hi))
    log_b = torch.special.log_ndtr(b)
    if two.numel() == 0:
        return -log_b
    a = torch.where(upper, -z_hi, z_lo)[two]
    gap = (torch.special.log_ndtr(a) - log_b[two]).clamp(max=-1e-12)
    return -log_b.index_add(0, two, torch.log(-torch.expm1(gap)))
