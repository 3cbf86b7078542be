"""The result of choosing the effects: the chosen fit and the trace of every candidate
tested (docs/diagnose.md §5.5); `select.forward_backward` builds it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from lads.diagnose.config import CONFIG
from lads.diagnose.fit.model import Fit
from lads.diagnose.selection.compare import Comparison


@dataclass
class Step:
    """One candidate evaluated at one forward step (the selection trace)."""

    step: int
    candidate: str
    delta_loss: float
    se: float
    delta_bic: float
    at_bound: bool
    accepted: bool = False
    support: Comparison | None = None
    screened: bool = False  # fitted on the screening rows only (not shortlisted)
    z: float = 0.0  # the held-out directional score in cluster SEs (the acceptance test)
    crossfit: bool = False  # support pooled with cross-fitted training groups

    @classmethod
    def of(cls, step: int, label: str, c: Comparison, at_bound: bool, **kw: Any) -> Step:
        return cls(step, label, c.delta, c.se, c.delta_bic, at_bound, z=c.z, **kw)

    def to_json(self) -> dict[str, Any]:
        out = {
            "step": self.step,
            "candidate": self.candidate,
            "delta_loss": self.delta_loss,
            "se": self.se,
            "z": self.z,
            "delta_bic": self.delta_bic,
            "at_bound": self.at_bound,
            "accepted": self.accepted,
            "screened": self.screened,
        }
        if self.support is not None:
            out["class_rows"] = {
                "delta_loss": self.support.delta,
                "se": self.support.se,
                "t": self.support.delta / max(self.support.se, 1e-300),
                "groups": self.support.groups,
                "statistic": "mean of group mean gains"
                + (", held-out and cross-fitted training groups" if self.crossfit else ""),
            }
        return out


@dataclass
class Selection:
    """Result of forward + backward selection on one training sample."""

    fit: Fit
    baseline: Fit
    trace: list[Step] = field(default_factory=list)
    first_step: dict[str, Comparison] = field(default_factory=dict)
    # Every model fitted on all the training rows, and those fitted on the screening rows
    # only, by set of effects: the starts of the stability resamples (`parallel.fit_warm`).
    fitted: dict[frozenset[str], Fit] = field(default_factory=dict)
    screened_fits: dict[frozenset[str], Fit] = field(default_factory=dict)
    # The held-out gain an effect had to beat (`gain_floor`).
    floor: float = CONFIG.select.min_gain_nats

    def starts(self) -> dict[frozenset[str], Fit]:
        return {**self.screened_fits, **self.fitted}

    @property
    def labels(self) -> list[str]:
        return [e.label for e in self.fit.model.effects]
