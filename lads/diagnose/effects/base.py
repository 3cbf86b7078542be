"""What every effect module builds on: the catalogue entry, the fitted candidate and the
helpers their terms share.

An effect module (one per catalogue family, `catalogue.FAMILIES`) declares its entries
(`INFOS`: id, key, parameters with units, bounds, confounds) and offers candidates for a
design (`candidates(offer)`). A candidate owns a few parameters (natural units, box bounds
read from its entry) and contributes any of:
    ln_term(theta, d)       added to the predicted ln I (most physical effects: factors on P)
    transfer(theta, d, mu)  a map applied to the predicted ln I last (encoding effects)
    log_survival(theta, d)  added to ln P(return) (dropout mechanisms)
    penalty(theta)          a small ridge that pins directions the global gain also spans
Terms are torch float64 so the fitter gets exact gradients; `export` turns the fitted vector
into report.json parameters named as in the catalogue.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from lads.diagnose.config import CONFIG
from lads.diagnose.fit.design import Design
from lads.physics.materials import ClassRoles, class_roles

Tensor = torch.Tensor
Bound = tuple[float | None, float | None]
RIDGE = CONFIG.effects.ridge
MIN_CLASS_ROWS = CONFIG.effects.min_class_rows
# Glossy and retro-reflective effects are tied to named classes (no search over classes, so
# no extra multiple testing) and act on few points: a sign is ~0.1 % of a scan, ~190 rows in
# six 40k-point scans, and its x5-x50 gain is plain in 50 rows.
MIN_CONFINED_ROWS = CONFIG.effects.min_confined_rows
# A fitted parameter name's catalogue name: "x[3]" is per-ring "x", "ln_scale_car" is the
# per-class "ln_scale_<class>".
_RING_SUFFIX = re.compile(r"\[\d+\]$")
_PER_CLASS = ("ln_scale_", "wet_share_")


@dataclass(frozen=True, slots=True)
class EffectInfo:
    """One catalogue entry.

    Attributes:
        id: stable ID, e.g. "C5".
        key: stable snake_case key, e.g. "atmospheric_attenuation".
        name: the name printed in reports.
        params: parameter names, units in the names.
        bounds: (low, high) per parameter, the box the fitter searches (None: free, or set
            from the data); per-ring and per-class parameters share one bound. Bounds listed
            in `encoded` are in stored units of an 8-bit encoding (0-255) and scale with the
            data's encoding.
        confounds: IDs of effects it is known to be confused with (docs/diagnose.md §5.3).
        kind: "intensity", "dropout" or "both".
        encoded: parameters whose bounds are in 8-bit stored units.
        offered: False for an entry the fitter does not offer yet (no term).
    """

    id: str
    key: str
    name: str
    params: tuple[str, ...]
    bounds: tuple[Bound, ...]
    confounds: tuple[str, ...]
    kind: str
    encoded: tuple[str, ...] = ()
    offered: bool = True

    def bound(self, name: str, max_value: float = 255.0) -> tuple[float, float]:
        """(low, high) of a fitted parameter (a catalogue name, or a per-ring "x[k]" or
        per-class "ln_scale_<name>" expansion of one), in the data's stored units.

        Raises:
            KeyError: the entry has no such parameter, or its bound is not a number.
        """
        param = catalogue_name(name)
        if param not in self.params:
            raise KeyError(f"{self.id}: no parameter '{param}' (it has {', '.join(self.params)})")
        lo, hi = self.bounds[self.params.index(param)]
        if lo is None or hi is None:
            raise KeyError(f"{self.id}: parameter '{param}' has no numeric bound")
        if param in self.encoded and max_value < 2:
            # A float encoding (full scale 1) scales the 8-bit bound by its full scale.
            return lo * max_value / 255.0, hi * max_value / 255.0
        return lo, hi


def catalogue_name(name: str) -> str:
    """The catalogue parameter a fitted parameter name expands ("x[3]" -> "x",
    "ln_scale_car" -> "ln_scale_<class>")."""
    name = _RING_SUFFIX.sub("", name)
    for prefix in _PER_CLASS:
        if name.startswith(prefix):
            return f"{prefix}<class>"
    return name


@dataclass
class Effect:
    """One candidate (a catalogue entry, possibly confined to one class).

    Attributes:
        info: the catalogue entry.
        label: unique name, e.g. "C3s[car]".
        names: parameter names of the fitted vector (per-ring vectors expanded, "x[k]").
        lower, upper: (P,) box bounds in natural units (-inf/inf for free).
        starts: initial vectors to try (the best on the training loss is kept).
        scalar: (P,) bool, parameters whose being at a bound disqualifies the effect.
        class_index: the class it is confined to, or -1.
        domain: for an effect confined to rows its fit chooses (an azimuth sector, a few
            rings): (numpy theta of this effect, design) -> (N,) bool, the rows it acts on.
            The held-out test then also reads those rows alone (selection/support.py domain_rows).
    """

    info: EffectInfo
    label: str
    names: tuple[str, ...]
    lower: npt.NDArray[np.float64]
    upper: npt.NDArray[np.float64]
    starts: list[npt.NDArray[np.float64]]
    scalar: npt.NDArray[np.bool_]
    class_index: int = -1
    class_name: str | None = None
    ln_term: Callable[[Tensor, Design], Tensor] | None = None
    transfer: Callable[[Tensor, Design, Tensor], Tensor] | None = None
    log_survival: Callable[[Tensor, Design], Tensor] | None = None
    penalty: Callable[[Tensor], Tensor] | None = None
    exporter: Callable[[npt.NDArray[np.float64]], dict[str, Any]] | None = None
    domain: Callable[[npt.NDArray[np.float64], Design], npt.NDArray[np.bool_]] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def size(self) -> int:
        return len(self.names)

    def export(self, theta: npt.NDArray[np.float64]) -> dict[str, Any]:
        """Report parameters (catalogue names) from the fitted vector."""
        if self.exporter is not None:
            return self.exporter(theta)
        return {n: float(v) for n, v in zip(self.names, theta, strict=True)}


@dataclass(frozen=True)
class Offer:
    """What every effect module reads to decide its candidates for one design.

    Attributes:
        d: the design.
        train_rows: rows the selection fits on (None: all); effects whose shape is chosen
            from the data (an azimuth sector, odd rings) look at these rows only.
        counts: (n_classes,) rows per class of the design.
        roles: the design's classes by surface role (materials.yaml), or None unlabelled.
    """

    d: Design
    train_rows: npt.NDArray[np.int64] | None
    counts: npt.NDArray[np.int64]
    roles: ClassRoles | None

    @classmethod
    def of(cls, d: Design, train_rows: npt.NDArray[np.int64] | None) -> Offer:
        known = d.class_index.numpy()
        counts = np.bincount(known[known >= 0], minlength=len(d.class_names))
        roles = None if d.label_set is None else class_roles(d.label_set)
        return cls(d, train_rows, counts, roles)

    def has_role(self, ci: int, role: str) -> bool:
        """Whether class index `ci` of the design has a surface role (a `ClassRoles` field:
        "clearcoat", "retroreflective", "road_like")."""
        return self.roles is not None and self.d.classes[ci] in getattr(self.roles, role)

    @functools.cached_property
    def frequent(self) -> list[int]:
        """Class indices with enough rows for a per-class term (MIN_CLASS_ROWS)."""
        return [ci for ci in range(len(self.d.class_names)) if self.counts[ci] >= MIN_CLASS_ROWS]


def entry(
    info: EffectInfo,
    names: tuple[str, ...],
    starts: list[list[float]],
    d: Design,
    *,
    label: str | None = None,
    scalar: list[bool] | None = None,
    **kwargs: Any,
) -> Effect:
    """A candidate of `info` fitting `names`, bounded as the catalogue entry says."""
    bounds = [info.bound(n, d.max_value) for n in names]
    return Effect(
        info=info,
        label=label or info.id,
        names=names,
        lower=np.array([b[0] for b in bounds], dtype=np.float64),
        upper=np.array([b[1] for b in bounds], dtype=np.float64),
        starts=[np.asarray(s, dtype=np.float64) for s in starts],
        scalar=np.array(scalar if scalar is not None else [True] * len(names)),
        **kwargs,
    )


def ring_vector(prefix: str, n: int) -> tuple[str, ...]:
    """Per-ring parameter names "prefix[0]" .. "prefix[n-1]"."""
    return tuple(f"{prefix}[{k}]" for k in range(n))


def phi_log(z: Tensor) -> Tensor:
    """ln Phi(z), stable in both tails."""
    return torch.special.log_ndtr(z)


def training_residual(
    d: Design, train_rows: npt.NDArray[np.int64] | None
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """The training rows whose intensity enters the fit, and ln I_real - ln I_sim there."""
    rows = np.arange(len(d)) if train_rows is None else np.asarray(train_rows)
    rows = rows[d.fits_intensity[rows]]
    return rows, (d.y.numpy() - d.ln_sim.numpy())[rows]
