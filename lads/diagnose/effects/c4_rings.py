"""C4 per-ring gain (+ ln g_ring, gains summing to 0; or on a few odd rings only) and C4o
per-ring offset (I + b_ring in stored units, before the ln).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
from scipy import stats

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.base import (
    Effect,
    EffectInfo,
    Offer,
    entry,
    ring_vector,
    training_residual,
)
from lads.diagnose.fit.design import Design

INFOS = (
    EffectInfo("C4", "ring_gain", "Per-ring gain", ("ln_gain_by_ring",), ((-1.0, 1.0),),
               ("C1", "C2"), "intensity"),
    EffectInfo("C4o", "ring_offset", "Per-ring offset (encoded units)", ("offset_by_ring",),
               ((-20.0, 20.0),), ("C9",), "intensity", encoded=("offset_by_ring",)),
)  # fmt: skip
C4, C4O = INFOS
# C4 on a few rings (`_few_ring_gains`): rings whose training residual stands out at this
# family-wise level over all rings, at most MAX_FEW_RINGS of them (more is the full C4's job).
FEW_RINGS_LEVEL = CONFIG.effects.few_rings_level
MAX_FEW_RINGS = CONFIG.effects.max_few_rings
ODD_RING_ROUNDS = CONFIG.effects.odd_ring_rounds
# Log-spaced range bins (to RANGE_BIN_TOP_M) within which a ring is compared with the others.
RANGE_BINS = CONFIG.effects.range_bins
RANGE_BIN_TOP_M = CONFIG.effects.range_bin_top_m


def candidates(offer: Offer) -> list[Effect]:
    """On a multi-ring design: C4 on every ring, C4 on the odd rings (if any), C4o."""
    d = offer.d
    n = d.n_rings
    if n <= 1:
        return []
    out = [
        entry(
            C4,
            ring_vector("ln_gain_by_ring", n),
            [[0.0] * n],
            d,
            scalar=[False] * n,
            ln_term=lambda th, dd: th[dd.ring],
            penalty=lambda th: 10.0 * th.sum() ** 2,
            exporter=lambda th: {"ln_gain_by_ring": [float(v) for v in th - th.mean()]},
        )
    ]
    few = _few_ring_gains(d, odd_rings(d, offer.train_rows))
    if few is not None:
        out.append(few)
    out.append(_offsets(d))
    return out


def _offsets(d: Design) -> Effect:
    n = d.n_rings
    off = C4O.bound("offset_by_ring", d.max_value)[1]
    # Offsets sum to zero like C4's gains: a common offset is the encoding's (C9), and
    # left free here it let 64 ring offsets stand in for a global offset (half the
    # rings of the real KITTI fit sat at the bound) or for a range falloff.
    return entry(
        C4O,
        ring_vector("offset_by_ring", n),
        [[0.0] * n],
        d,
        scalar=[False] * n,
        penalty=lambda th: 10.0 * (th.sum() / off) ** 2,
        transfer=lambda th, dd, mu: torch.log(
            (torch.exp(mu) - dd.half_step + th[dd.ring]).clamp_min(0.0) + dd.half_step
        ),
        exporter=lambda th: {"offset_by_ring": [float(v) for v in th]},
    )


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

    return entry(
        C4,
        tuple(f"ln_gain_by_ring[{r}]" for r in rings),
        [[0.0] * k],
        d,
        label="C4[few_rings]",
        scalar=[False] * k,
        ln_term=lambda th, dd: torch.cat([th, th.new_zeros(1)])[lookup[dd.ring]],
        exporter=export,
        domain=lambda th, dd: np.isin(dd.ring.numpy(), rings),
    )


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
    rows, r = training_residual(d, train_rows)
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
    mean = np.divide(
        np.bincount(inv, weights=r * ref), ref_n, out=np.zeros_like(ref_n), where=ref_n > 0
    )
    dev = np.where(ref_n[inv] > 0, r - mean[inv], 0.0)  # no reference: nothing to compare
    _, by = np.unique(ring * (int(d.group.max()) + 1) + d.group[rows], return_inverse=True)
    sums = np.bincount(by, weights=dev)
    ring_of = np.zeros(len(sums), dtype=np.int64)
    ring_of[by] = ring
    total = np.bincount(ring_of, weights=sums, minlength=n)
    spread = np.sqrt(np.bincount(ring_of, weights=sums**2, minlength=n))
    return np.divide(total, spread, out=np.zeros(n), where=spread > 0)
