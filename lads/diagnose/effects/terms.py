"""Candidate effects as terms of the joint intensity-and-return likelihood (catalogue.py).

An effect owns a few parameters (natural units, box bounds) and contributes any of:
    ln_term(theta, d)    added to the predicted ln I (most physical effects: factors on P)
    transfer(theta, d, mu)  a map applied to the predicted ln I last (encoding effects)
    log_survival(theta, d)  added to ln P(return) (dropout mechanisms)
    penalty(theta)       a small ridge that pins directions the global gain also spans
Terms are torch float64 so the fitter gets exact gradients; `export` turns the fitted vector
into report.json parameters named as in the catalogue.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
from scipy import stats

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.catalogue import CATALOGUE, EffectInfo
from lads.diagnose.fit.design import Design

Tensor = torch.Tensor
GLOSSY_CLASS_WORDS = ("car", "truck", "bus", "vehicle", "trailer", "motorcycle")
RETRO_CLASS_WORDS = ("traffic-sign", "traffic_sign", "sign", "pole-sign", "traffic_cone")
WET_CLASS_WORDS = ("road", "sidewalk", "parking", "lane-marking", "driveable_surface",
                   "other-ground", "other_flat")  # fmt: skip
MIN_CLASS_ROWS = CONFIG.effects.min_class_rows
# Glossy and retro-reflective effects are tied to named classes (no search over classes, so
# no extra multiple testing) and act on few points: a sign is ~0.1 % of a scan, ~190 rows in
# six 40k-point scans, and its x5-x50 gain is plain in 50 rows.
MIN_CONFINED_ROWS = CONFIG.effects.min_confined_rows
RIDGE = CONFIG.effects.ridge
SECTOR_SOFTNESS_DEG = CONFIG.effects.sector_softness_deg
# C4 on a few rings (`_few_ring_gains`): rings whose training residual stands out at this
# family-wise level over all rings, at most MAX_FEW_RINGS of them (more is the full C4's job).
FEW_RINGS_LEVEL = CONFIG.effects.few_rings_level
MAX_FEW_RINGS = CONFIG.effects.max_few_rings
ODD_RING_ROUNDS = CONFIG.effects.odd_ring_rounds
# Log-spaced range bins (to RANGE_BIN_TOP_M) within which a ring is compared with the others.
RANGE_BINS = CONFIG.effects.range_bins
RANGE_BIN_TOP_M = CONFIG.effects.range_bin_top_m


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
            The held-out test then also reads those rows alone (select.domain_rows).
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


def _entry(
    id_: str,
    names: tuple[str, ...],
    bounds: list[tuple[float, float]],
    starts: list[list[float]],
    *,
    label: str | None = None,
    scalar: list[bool] | None = None,
    **kwargs: Any,
) -> Effect:
    lower = np.array([b[0] for b in bounds], dtype=np.float64)
    upper = np.array([b[1] for b in bounds], dtype=np.float64)
    return Effect(
        info=CATALOGUE[id_],
        label=label or id_,
        names=names,
        lower=lower,
        upper=upper,
        starts=[np.asarray(s, dtype=np.float64) for s in starts],
        scalar=np.array(scalar if scalar is not None else [True] * len(names)),
        **kwargs,
    )


def _ring_vector(prefix: str, n: int) -> tuple[str, ...]:
    return tuple(f"{prefix}[{k}]" for k in range(n))


def _edge_cover(d: Design, e0: Tensor) -> Tensor:
    """(N,) E[exp(-e / e0)] with the edge distance e uniform on edge_beams +- span / 2
    (clipped at 0): on a thinned or gappy scan the edge lies somewhere in the gap, and
    exp(-e / e0) at the gap's midpoint understates how close some of those returns are."""
    lo = (d.edge_beams - 0.5 * d.edge_span_beams).clamp_min(0.0)
    hi = d.edge_beams + 0.5 * d.edge_span_beams
    width = hi - lo
    wide = width > 1e-6
    mean = e0 * (torch.exp(-lo / e0) - torch.exp(-hi / e0)) / torch.where(wide, width, 1.0)
    return torch.where(wide, mean, torch.exp(-d.edge_beams / e0))


def _phi_log(z: Tensor) -> Tensor:
    """ln Phi(z), stable in both tails."""
    return torch.special.log_ndtr(z)


def _in_sector(az: Tensor, start: Tensor, width: Tensor) -> Tensor:
    """Smooth indicator of azimuth in [start, start + width) (degrees, wrapping)."""
    offset = torch.remainder(az - start, 360.0)
    inside_low = torch.sigmoid(offset / SECTOR_SOFTNESS_DEG)
    inside_high = torch.sigmoid((width - offset) / SECTOR_SOFTNESS_DEG)
    return inside_low * inside_high


def candidates(d: Design, *, train_rows: npt.NDArray[np.int64] | None = None) -> list[Effect]:
    """The catalogue effects the design can inform (C0 is part of the baseline).

    Rules (docs/diagnose.md §5.3 "Needs"): class-confined effects only for labelled classes with
    enough rows; C10 only with >= 5 scans; dropout effects only for paired designs.
    """
    out: list[Effect] = []
    n = d.n_rings
    ln_r_ref = float(d.ln_range.mean())
    out.append(_entry("C1", ("delta_n",), [(-2.5, 2.0)], [[0.0]],
                      ln_term=lambda th, dd: -th[0] * (dd.ln_range - ln_r_ref)))  # fmt: skip
    out.append(
        _entry(
            "C2", ("r0_m", "k"), [(0.5, 12.0), (1.0, 8.0)], [[1.5, 3.0], [3.0, 3.0], [6.0, 3.0]],
            ln_term=lambda th, dd: -torch.log1p((th[0] / dd.range_m.clamp_min(0.1)) ** th[1]),
        )
    )  # fmt: skip
    out.append(_entry("C3", ("p_extra",), [(-1.0, 2.0)], [[0.0]],
                      ln_term=lambda th, dd: th[0] * dd.ln_cos))  # fmt: skip
    out.append(_oren_nayar())
    names = np.array(d.class_names, dtype=object)
    counts = np.bincount(d.class_index.numpy()[d.class_index.numpy() >= 0], minlength=len(names))
    for ci, cname in enumerate(d.class_names):
        if counts[ci] < MIN_CONFINED_ROWS:
            continue
        lname = cname.lower()
        if any(w in lname for w in GLOSSY_CLASS_WORDS):
            out.append(_specular(ci, cname))
        if any(w in lname for w in RETRO_CLASS_WORDS):
            out.append(
                _entry(
                    "C3r",
                    ("ln_gain",),
                    [(0.0, 6.91)],
                    [[1.0]],
                    label=f"C3r[{cname}]",
                    class_index=ci,
                    class_name=cname,
                    ln_term=lambda th, dd, ci=ci: torch.where(
                        dd.class_index == ci, th[0] - dd.ln_cos, torch.zeros_like(dd.ln_cos)
                    ),
                )  # fmt: skip
            )
    del names
    if n > 1:
        out.append(
            _entry(
                "C4",
                _ring_vector("ln_gain_by_ring", n),
                [(-1.0, 1.0)] * n,
                [[0.0] * n],
                scalar=[False] * n,
                ln_term=lambda th, dd: th[dd.ring],
                penalty=lambda th: 10.0 * th.sum() ** 2,
                exporter=lambda th: {"ln_gain_by_ring": [float(v) for v in th - th.mean()]},
            )
        )
        few = _few_ring_gains(d, odd_rings(d, train_rows))
        if few is not None:
            out.append(few)
        off = 20.0 * d.max_value / 255.0 if d.max_value < 2 else 20.0
        # Offsets sum to zero like C4's gains: a common offset is the encoding's (C9), and
        # left free here it let 64 ring offsets stand in for a global offset (half the
        # rings of the real KITTI fit sat at the bound) or for a range falloff.
        out.append(
            _entry(
                "C4o", _ring_vector("offset_by_ring", n), [(-off, off)] * n, [[0.0] * n],
                scalar=[False] * n,
                penalty=lambda th, off=off: 10.0 * (th.sum() / off) ** 2,
                transfer=lambda th, dd, mu: torch.log(
                    (torch.exp(mu) - dd.half_step + th[dd.ring]).clamp_min(0.0) + dd.half_step),
                exporter=lambda th: {"offset_by_ring": [float(v) for v in th]},
            )
        )  # fmt: skip
    out.append(_entry("C5", ("alpha_per_m",), [(0.0, 0.5)], [[0.001]],
                      ln_term=lambda th, dd: -2.0 * th[0] * dd.range_m))  # fmt: skip
    frequent = [ci for ci in range(len(d.class_names)) if counts[ci] >= MIN_CLASS_ROWS]
    if len(frequent) >= 2:
        out.append(_class_scale(d, frequent))
        # One class at a time as well: a mismatch confined to one class is diluted in the
        # joint vector, whose other entries fit object-level noise in the training groups
        # and give the held-out gain back (a shifted vegetation class went unnoticed).
        out += [_one_class_scale(ci, d.class_names[ci]) for ci in frequent]
    wet = [ci for ci in frequent if any(w == d.class_names[ci].lower() for w in WET_CLASS_WORDS)]
    if wet:
        out.append(_wet(d, wet))
    out.append(
        _entry(
            "C8", ("a", "e0_beams"), [(0.0, 0.9), (0.5, 3.0)], [[0.3, 1.0]],
            ln_term=lambda th, dd: torch.log1p(-th[0] * _edge_cover(dd, th[1])),
        )
    )  # fmt: skip
    out.append(_encoding(d))
    if d.n_scans >= 5:
        out.append(_entry("C10", ("beta",), [(0.0, 1.5)], [[0.3]],
                          ln_term=lambda th, dd: -th[0] * dd.scan_ln_mean))  # fmt: skip
    out.append(_blockage(d, train_rows))
    if d.paired:
        out.extend(_dropout_effects(d, n))
    return out


def _oren_nayar() -> Effect:
    """C3 as the Oren-Nayar law seen monostatically, relative to Lambert.

    With incidence = exitance = theta and no azimuth difference, the rough-surface radiance
    over Lambert's is A + B sin(theta) tan(theta), A = 1 - 0.5 s^2 / (s^2 + 0.33), B = 0.45
    s^2 / (s^2 + 0.09), s the facet slope spread (rad). It rises towards grazing where cos^p
    only bends, so a rough ground fitted as cos^p leaves a range-like residual that ring
    offsets and attenuation then chase."""

    def term(th: Tensor, dd: Design) -> Tensor:
        s2 = th[0] ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        cos = dd.cos.clamp(0.05, 1.0)
        lobe = torch.log(a + b * (1.0 - cos**2) / cos)
        return torch.where(dd.normal_ok, lobe, torch.zeros_like(cos))

    # sigma = 0 is Lambert itself, so a fit there gains nothing and is rejected as at bound
    # like C5's alpha = 0.
    return _entry("C3", ("sigma_rad",), [(0.0, 0.6)], [[0.2]], label="C3[oren_nayar]",
                  ln_term=term)  # fmt: skip


def _specular(ci: int, cname: str) -> Effect:
    def term(th: Tensor, dd: Design) -> Tensor:
        cos = dd.cos.clamp(0.05, 1.0)
        lobe = torch.log1p(th[0] * cos ** (th[1] - 1.0))
        return torch.where((dd.class_index == ci) & dd.normal_ok, lobe, torch.zeros_like(cos))

    return _entry("C3s", ("k_s", "m"), [(0.0, 5.0), (5.0, 300.0)], [[1.0, 20.0], [1.0, 80.0]],
                  label=f"C3s[{cname}]", class_index=ci, class_name=cname,
                  ln_term=term)  # fmt: skip


def _class_scale(d: Design, frequent: list[int]) -> Effect:
    names = tuple(f"ln_scale_{d.class_names[ci]}" for ci in frequent)
    lookup = torch.full((len(d.class_names) + 1,), -1, dtype=torch.long)
    for j, ci in enumerate(frequent):
        lookup[ci] = j

    def term(th: Tensor, dd: Design) -> Tensor:
        idx = lookup[dd.class_index.clamp_min(-1)]  # -1 (unknown) reads the last slot: -1
        padded = torch.cat([th, torch.zeros(1, dtype=th.dtype)])
        return padded[idx]

    return _entry("C6", names, [(-1.5, 1.5)] * len(names), [[0.0] * len(names)],
                  scalar=[False] * len(names), ln_term=term,
                  penalty=lambda th: RIDGE * (th**2).sum())  # fmt: skip


def _one_class_scale(ci: int, cname: str) -> Effect:
    def term(th: Tensor, dd: Design) -> Tensor:
        return torch.where(dd.class_index == ci, th[0].expand_as(dd.cos), torch.zeros_like(dd.cos))

    return _entry("C6", (f"ln_scale_{cname}",), [(-1.5, 1.5)], [[0.0]], label=f"C6[{cname}]",
                  class_index=ci, class_name=cname, ln_term=term)  # fmt: skip


def _wet(d: Design, wet: list[int]) -> Effect:
    """C7 over the road-like classes, each with its own wet share w in [0, 1].

    A film darkens a wet surface by (1 - f) and, beyond theta_c, mirrors the beam away (no
    return); on a class wet in a share w of its area both act on that share. Pooling every
    road-like class at w = 1 wets the dry ones too (a dry car park that keeps its grazing
    returns refutes the cutoff), while one candidate per class splits one film over several
    forward steps, and a per-ring dropout that spans them all wins the first. Fitting w per
    class names the wet classes in one step; w at 0 or 1 is the expected answer, not a bound.
    """
    lookup = torch.zeros(len(d.class_names) + 1, dtype=torch.long)  # 0: not road-like
    for j, ci in enumerate(wet):
        lookup[ci] = j + 1
    names = tuple(f"wet_share_{d.class_names[ci]}" for ci in wet)

    def share(th: Tensor, dd: Design) -> Tensor:
        padded = torch.cat([torch.zeros(1, dtype=th.dtype), th[3:].clamp(1e-6, 1.0 - 1e-6)])
        return padded[lookup[dd.class_index.clamp_min(-1)]]

    def term(th: Tensor, dd: Design) -> Tensor:
        return torch.log1p(-th[0] * share(th, dd))

    def survival(th: Tensor, dd: Design) -> Tensor:
        # The cutoff is sharp in cos(theta); its fitted softness takes up the scatter of the
        # estimated normals, which a fixed narrow edge turned into huge per-row penalties.
        w = share(th, dd)
        z = (dd.cos - torch.cos(th[1] * math.pi / 180.0)) / th[2]
        kept = torch.logaddexp(torch.log1p(-w), torch.log(w) + _phi_log(z))
        return torch.where(dd.normal_ok, kept, torch.zeros_like(kept))

    def export(th: npt.NDArray[np.float64]) -> dict[str, Any]:
        out: dict[str, Any] = {"f": float(th[0]), "theta_c_deg": float(th[1]),
                               "cos_softness": float(th[2])}  # fmt: skip
        out.update({n: float(v) for n, v in zip(names, th[3:], strict=True)})
        return out

    k = len(wet)
    eff = _entry("C7", ("f", "theta_c_deg", "cos_softness", *names),
                 [(0.0, 0.95), (50.0, 89.0), (0.005, 0.2)] + [(0.0, 1.0)] * k,
                 [[0.3, 75.0, 0.03] + [0.5] * k, [0.5, 60.0, 0.03] + [0.9] * k],
                 scalar=[True, True, False] + [False] * k, ln_term=term,
                 log_survival=survival, exporter=export)  # fmt: skip
    eff.extra["classes"] = [d.class_names[ci] for ci in wet]
    eff.extra["wet_share_names"] = names
    return eff


def _encoding(d: Design) -> Effect:
    ln_fs = math.log(d.full_scale)
    off = 20.0 * d.max_value / 255.0 if d.max_value < 2 else 20.0

    def transfer(th: Tensor, dd: Design, mu: Tensor) -> Tensor:
        intensity = (torch.exp(mu) - dd.half_step).clamp_min(0.0)
        # The power law acts on reflectivity (intensity / full scale), so gamma is unitless.
        powered = torch.exp(th[0] * (torch.log(intensity + 1e-12) - ln_fs) + ln_fs)
        return torch.log((powered + th[1]).clamp_min(0.0) + dd.half_step)

    clip = d.real_clip

    def export(th: npt.NDArray[np.float64]) -> dict[str, Any]:
        out = {"gamma": float(th[0]), "offset": float(th[1])}
        if clip is not None:
            # The clip is read off the data (design.clip_level), not fitted: its rows are
            # censored in every model, so they cannot bias gamma.
            out["i_max"] = clip
        return out

    eff = _entry("C9", ("gamma", "offset"), [(0.4, 1.5), (-off, off)], [[1.0, 0.0]],
                 transfer=transfer, exporter=export)  # fmt: skip
    if clip is not None:
        eff.extra["ci_floor"] = {"i_max": 0.5 * d.step}
    return eff


def _blockage(d: Design, train_rows: npt.NDArray[np.int64] | None) -> Effect:
    start, width = _darkest_sector(d, train_rows)

    def term(th: Tensor, dd: Design) -> Tensor:
        return torch.log1p(-th[2] * _in_sector(dd.azimuth_deg, th[0], th[1]))

    def survival(th: Tensor, dd: Design) -> Tensor:
        return torch.log1p(-th[3] * _in_sector(dd.azimuth_deg, th[0], th[1]))

    def sector(th: npt.NDArray[np.float64], dd: Design) -> npt.NDArray[np.bool_]:
        offset = np.remainder(dd.azimuth_deg.numpy() - th[0], 360.0)
        return offset < th[1]

    names = ("start_deg", "width_deg", "a", "drop_fraction")
    bounds = [(-360.0, 720.0), (2.0, 90.0), (0.0, 0.95), (0.0, 0.95)]
    eff = _entry("C11", names, bounds, [[start, width, 0.3, 0.05]],
                 scalar=[False, True, True, False], ln_term=term,
                 log_survival=survival if d.paired else None, domain=sector,
                 exporter=lambda th: {"start_deg": float(th[0] % 360.0),
                                      "width_deg": float(th[1]), "a": float(th[2]),
                                      "drop_fraction": float(th[3])})  # fmt: skip
    # The sector's edges lie between two azimuth samples, and every bootstrap resample has
    # the same samples: its spread cannot show that, so the CI is never narrower than one
    # sample spacing either side (analysis._ci).
    spacing = azimuth_spacing_deg(d)
    eff.extra["ci_floor"] = {"start_deg": spacing, "width_deg": spacing}
    return eff


def _few_ring_gains(d: Design, rings: list[int]) -> Effect | None:
    """C4 confined to `rings` (one gain each, the other rings at 0), or None without rings.

    One weak laser among 64 is 1.5 % of the rows: the full C4 pays for 63 gains fitted to
    noise and can lose on held-out rows. The rings are chosen on the training rows only
    (`odd_rings`), so the held-out test of this candidate is as honest as any other's.
    Exported like C4 (every ring, sum 0)."""
    if not rings:
        return None
    n, k = d.n_rings, len(rings)
    lookup = torch.full((n,), k, dtype=torch.long)  # k: the zero appended below
    lookup[torch.as_tensor(rings, dtype=torch.long)] = torch.arange(k)

    def export(th: npt.NDArray[np.float64]) -> dict[str, Any]:
        full = np.zeros(n)
        full[rings] = th
        return {"ln_gain_by_ring": [float(v) for v in full - full.mean()], "rings": list(rings)}

    return _entry(
        "C4", tuple(f"ln_gain_by_ring[{r}]" for r in rings), [(-1.0, 1.0)] * k, [[0.0] * k],
        label="C4[few_rings]", scalar=[False] * k,
        ln_term=lambda th, dd: torch.cat([th, th.new_zeros(1)])[lookup[dd.ring]],
        exporter=export, domain=lambda th, dd: np.isin(dd.ring.numpy(), rings),
    )  # fmt: skip


def odd_rings(d: Design, train_rows: npt.NDArray[np.int64] | None) -> list[int]:
    """Rings (in ring order; the MAX_FEW_RINGS strongest) whose `ring_z` passes a
    Bonferroni bar over the rings at FEW_RINGS_LEVEL.

    Rings that pass are left out of the reference and the test repeated until the set is
    stable: two weak rings in the cell means lifted the other rings' z enough to pass a
    null ring."""
    odd = np.zeros(d.n_rings, dtype=bool)
    bar = stats.norm.isf(FEW_RINGS_LEVEL / (2 * d.n_rings))
    for _ in range(ODD_RING_ROUNDS):
        z = ring_z(d, train_rows, reference=~odd)
        passed = np.abs(z) > bar
        if np.array_equal(passed, odd):
            break
        odd = passed
    order = np.argsort(-np.abs(z), kind="stable")
    return sorted(int(k) for k in order[:MAX_FEW_RINGS] if odd[k])


def ring_z(
    d: Design,
    train_rows: npt.NDArray[np.int64] | None,
    reference: npt.NDArray[np.bool_] | None = None,
) -> npt.NDArray[np.float64]:
    """(n_rings,) cluster z of each ring's training residual ln I_real - ln I_sim against the
    `reference` rings' (default: all) at the same scan, class and range.

    Comparing within (scan, class, range bin) cells takes out what varies with range, class
    or scan (C1, C2, C5, C6, C10) before rings are compared. Each ring's deviations are
    summed per group and tested as sum / sqrt(sum of squared group sums): the z under "no
    ring effect", with groups (tiles) as the independent units."""
    rows, r = _training_residual(d, train_rows)
    n = d.n_rings
    if r.size == 0:
        return np.zeros(n)
    ln_r = np.log(np.maximum(d.range_m.numpy()[rows], 1.0)) / math.log(RANGE_BIN_TOP_M)
    range_bin = np.clip((ln_r * RANGE_BINS).astype(np.int64), 0, RANGE_BINS - 1)
    cls = d.class_index.numpy()[rows].astype(np.int64) + 1
    scan = d.scan.numpy()[rows].astype(np.int64)
    cell = (scan * (len(d.class_names) + 1) + cls) * RANGE_BINS + range_bin
    ring = d.ring.numpy()[rows].astype(np.int64)
    ref = np.ones(len(ring), dtype=bool) if reference is None else reference[ring]
    _, inv = np.unique(cell, return_inverse=True)
    ref_n = np.bincount(inv, weights=ref.astype(np.float64))
    mean = np.divide(np.bincount(inv, weights=r * ref), ref_n, out=np.zeros_like(ref_n),
                     where=ref_n > 0)  # fmt: skip
    dev = np.where(ref_n[inv] > 0, r - mean[inv], 0.0)  # no reference: nothing to compare
    _, by = np.unique(ring * (int(d.group.max()) + 1) + d.group[rows], return_inverse=True)
    sums = np.bincount(by, weights=dev)
    ring_of = np.zeros(len(sums), dtype=np.int64)
    ring_of[by] = ring
    total = np.bincount(ring_of, weights=sums, minlength=n)
    spread = np.sqrt(np.bincount(ring_of, weights=sums**2, minlength=n))
    return np.divide(total, spread, out=np.zeros(n), where=spread > 0)


def _training_residual(
    d: Design, train_rows: npt.NDArray[np.int64] | None
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """The training rows whose intensity enters the fit, and ln I_real - ln I_sim there."""
    rows = np.arange(len(d)) if train_rows is None else np.asarray(train_rows)
    rows = rows[d.fits_intensity[rows]]
    return rows, (d.y.numpy() - d.ln_sim.numpy())[rows]


def azimuth_spacing_deg(d: Design) -> float:
    """Median azimuth step (degrees) between consecutive returns of a ring in a scan."""
    key = d.scan.numpy().astype(np.int64) * (d.n_rings + 1) + d.ring.numpy().astype(np.int64)
    az = d.azimuth_deg.numpy().astype(np.float64)
    order = np.lexsort((az, key))
    same = key[order][1:] == key[order][:-1]
    steps = np.diff(az[order])[same]
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else 0.0


def _darkest_sector(d: Design, train_rows: npt.NDArray[np.int64] | None) -> tuple[float, float]:
    """Start and width (degrees) of the azimuth window whose mean residual is lowest."""
    rows, r = _training_residual(d, train_rows)
    az = d.azimuth_deg.numpy()[rows]
    if r.size == 0:
        return 0.0, 20.0
    bins = (az // 5.0).astype(np.int64) % 72
    sums = np.bincount(bins, weights=r - np.median(r), minlength=72)
    counts = np.bincount(bins, minlength=72)
    best = (0.0, 0.0, 20.0)
    for width in (2, 4, 6, 8, 12):  # in 5-degree bins: 10-60 degrees
        s = sum(np.roll(sums, -k) for k in range(width))
        c = sum(np.roll(counts, -k) for k in range(width))
        score = s / np.sqrt(np.maximum(c, 1))
        k = int(np.argmin(score))
        if score[k] < best[0]:
            best = (float(score[k]), 5.0 * k, 5.0 * width)
    return best[1], best[2]


def _dropout_effects(d: Design, n: int) -> list[Effect]:
    ln_tau0 = float(np.quantile(d.ln_sim.numpy(), 0.02)) - 0.5
    # latent_share (model.py: the share of y - mu the detector sees) lives on [0, 1] and its
    # ends are the two textbook models, so sitting there says nothing against the effect.
    d1 = _entry("D1", ("ln_tau", "s", "latent_share"), [(-30.0, 10.0), (0.05, 3.0), (0.0, 1.0)],
                [[ln_tau0, 0.5, 0.1], [ln_tau0, 0.5, 0.9]], scalar=[True, True, False])  # fmt: skip
    d1.extra["threshold"] = True
    d2 = _entry(
        "D2", ("cos_c", "s_cos"), [(0.0, 0.9), (0.01, 0.5)], [[0.1, 0.05]],
        log_survival=lambda th, dd: torch.where(
            dd.normal_ok, _phi_log((dd.cos - th[0]) / th[1]), torch.zeros_like(dd.cos)),
    )  # fmt: skip
    d3 = _entry(
        "D3", _ring_vector("p_drop_by_ring", n), [(0.0, 0.999)] * n, [[0.0] * n],
        scalar=[False] * n,
        log_survival=lambda th, dd: torch.log1p(-th[dd.ring]),
        penalty=lambda th: RIDGE * th.sum(),
        exporter=lambda th: {
            "rings": [int(k) for k in np.flatnonzero(th > 0.1)],
            "p_drop": [float(v) for v in th[th > 0.1]],
            "p_drop_by_ring": [float(v) for v in th],
        },
    )  # fmt: skip
    return [d1, d2, d3]
