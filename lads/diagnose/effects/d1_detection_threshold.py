"""D1 detection threshold, joint with intensity: P(return) = Phi((mu - ln_tau) / s), mu the
predicted ln I_real; latent_share in [0, 1] is the share of the real value's deviation from
mu that the detector also sees (1: the returned value itself is censored, Tobit). The
likelihood of the threshold lives in fit/likelihood.py (`extra["threshold"]`).
"""

from __future__ import annotations

import numpy as np

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry

INFOS = (
    EffectInfo("D1", "detection_threshold", "Detection threshold (joint with intensity)",
               ("ln_tau", "s", "latent_share"), ((-30.0, 10.0), (0.05, 3.0), (0.0, 1.0)),
               ("D2",), "dropout"),
)  # fmt: skip


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on paired designs, started below the faintest simulated returns."""
    d = offer.d
    if not d.paired:
        return []
    ln_tau0 = float(np.quantile(d.ln_sim.numpy(), 0.02)) - 0.5
    # latent_share (likelihood.py: the share of y - mu the detector sees) lives on [0, 1] and its
    # ends are the two textbook models, so sitting there says nothing against the effect.
    d1 = entry(
        INFOS[0],
        ("ln_tau", "s", "latent_share"),
        [[ln_tau0, 0.5, 0.1], [ln_tau0, 0.5, 0.9]],
        d,
        scalar=[True, True, False],
    )
    d1.extra["threshold"] = True
    return [d1]
