"""The design: the float64 tensors the likelihood reads, one row per beam
(`lads.diagnose.fit.from_table` makes them from beam tables, docs/diagnose.md §5.1)."""

from __future__ import annotations

import collections
import functools
import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

SUBSET_CACHE = 4


@dataclass(frozen=True)
class CensoredRows:
    """The rows of a design whose real value is an interval or one-sided (censor > 0).

    Attributes:
        rows: (C,) int64 row indices. censor, y_lo, y_hi: (C,) those rows' values.
        one_sided: (C,) bool, censor 2 or 3. two: (T,) int64 positions (into the C rows) of
            the two-sided intervals (censor 1).
    """

    rows: torch.Tensor
    censor: torch.Tensor
    y_lo: torch.Tensor
    y_hi: torch.Tensor
    one_sided: torch.Tensor
    two: torch.Tensor


@dataclass(frozen=True)
class Design:
    """Per-row tensors (float64 unless stated), all (N,).

    Attributes:
        y: ln(i_real + h) where returned, else 0.
        y_lo, y_hi, censor: the quantisation interval of y. Stored values are rounded to the
            encoding's step, so a value within LOW_STEPS (from_table) steps of 0 is an
            interval, not a point: censor 1 = interval [y_lo, y_hi], 2 = stored 0 (below
            y_hi), 3 = stored maximum (above y_lo, clipped), 0 = a point (y itself).
        ln_sim: ln(i_sim + h).
        sim_var: Var[ln(x + h)] for x uniform on i_sim's rounding interval (i_sim +- step / 2,
            clipped at 0); added to sigma^2 (errors in variables: a simulation stored at
            0.01 steps knows a value of 0.02 only to +-25 %).
        sim_shift: E[ln(x + h)] - ln(i_sim + h) for x on the same interval: uniform from
            ZERO_FIT_STEPS + 1 steps on (~0), below that imputed from the geometry
            (`_low_power`; about +0.39 at a stored 0). The detection threshold reads it (a
            power below half a step is not the power of a stored 0); intensity fits do not.
        sim_ok: bool, the simulated value is informative about the intensity: False where it
            is stored as 0, which may mean exactly 0 or anything below half a step (the
            mean of ln(x + h) then differs by 0.39), so only the return enters there.
        returned: bool, reality returned the beam.
        ln_range, range_m, cos, ln_cos (0 where the normal is ill-conditioned), normal_ok.
        ring, class_index (index into `classes`, -1 unknown), scan: int64.
        azimuth_deg, edge_beams, edge_span_beams, is_ground (bool), scan_ln_mean (mean
            ln_sim of the scan).
        group: int64 numpy group id per row (for splits and bootstraps).
        classes: class ids present, `class_index` points into it.
        class_names: name per entry of `classes`.
        label_set: the label set the class ids belong to (`lads.physics.materials`), or None.
        half_step, full_scale, max_value, step: the encoding in stored units.
        n_rings, n_scans: sizes of the categorical features.
        paired: False for unpaired pseudo-pairs (no dropout information).
        real_clip: the level (stored units) the real values are clipped at below the
            encoding's maximum (`clip_level`), or None; rows stored there are censor 3.
    """

    y: torch.Tensor
    y_lo: torch.Tensor
    y_hi: torch.Tensor
    censor: torch.Tensor
    ln_sim: torch.Tensor
    sim_var: torch.Tensor
    sim_shift: torch.Tensor
    sim_ok: torch.Tensor
    returned: torch.Tensor
    ln_range: torch.Tensor
    range_m: torch.Tensor
    cos: torch.Tensor
    ln_cos: torch.Tensor
    normal_ok: torch.Tensor
    ring: torch.Tensor
    class_index: torch.Tensor
    scan: torch.Tensor
    azimuth_deg: torch.Tensor
    edge_beams: torch.Tensor
    edge_span_beams: torch.Tensor
    is_ground: torch.Tensor
    scan_ln_mean: torch.Tensor
    group: npt.NDArray[np.int64]
    rows: npt.NDArray[np.int64]
    classes: tuple[int, ...]
    class_names: tuple[str, ...]
    half_step: float
    full_scale: float
    max_value: float
    step: float
    n_rings: int
    n_scans: int
    paired: bool
    real_clip: float | None = None
    label_set: str | None = None

    def __len__(self) -> int:
        return int(self.y.shape[0])

    @functools.cached_property
    def censored(self) -> CensoredRows:
        """The censored rows and what the likelihood reads of them (cached: a fit evaluates
        its likelihood ~30 times on one design)."""
        rows = torch.nonzero(self.censor > 0).squeeze(1)
        censor = self.censor[rows]
        one_sided = censor >= 2
        return CensoredRows(
            rows,
            censor,
            self.y_lo[rows],
            self.y_hi[rows],
            one_sided,
            torch.nonzero(~one_sided).squeeze(1),
        )

    @functools.cached_property
    def group_index(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        """(N,) index of each row's group among the distinct groups, and (G,) each group's
        row count. Cached: one held-out design is compared with every candidate of a
        selection, and sorting its groups each time was 6 % of a diagnosis."""
        return group_index(self.group)

    @property
    def fits_intensity(self) -> npt.NDArray[np.bool_]:
        """(N,) numpy bool: rows whose real intensity enters the fit (returned, sim_ok)."""
        return (self.returned & self.sim_ok).numpy()

    def rows_subset(self, idx: npt.NDArray[np.int64]) -> Design:
        """`subset(idx)`, remembered for the last SUBSET_CACHE row sets: every candidate of
        a selection step, and every start of a fit, trains on the same rows, and cutting
        them out again was 3 % of a diagnosis."""
        key = hashlib.blake2b(
            np.ascontiguousarray(idx, dtype=np.int64).tobytes(), digest_size=16
        ).digest()
        cache = self._subsets
        if key in cache:
            cache.move_to_end(key)
            return cache[key]
        sub = self.subset(idx)
        cache[key] = sub
        if len(cache) > SUBSET_CACHE:
            cache.popitem(last=False)
        return sub

    @functools.cached_property
    def _subsets(self) -> collections.OrderedDict[bytes, Design]:
        return collections.OrderedDict()

    def __getstate__(self) -> dict[str, Any]:
        # Caches stay with the process that filled them: a worker gets the columns only.
        return {k: v for k, v in self.__dict__.items() if k in self.__dataclass_fields__}

    def subset(self, idx: npt.NDArray[np.int64]) -> Design:
        """The design restricted to rows `idx` (numpy indices)."""
        t = torch.as_tensor(idx, dtype=torch.long)
        kwargs: dict[str, Any] = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if isinstance(value, torch.Tensor):
                kwargs[name] = value[t]
            elif isinstance(value, np.ndarray):
                kwargs[name] = value[idx]
            else:
                kwargs[name] = value
        return Design(**kwargs)


def evenly_spaced(n: int, cap: int) -> npt.NDArray[np.int64]:
    """Indices of at most `cap` of `n` rows, evenly spaced in order (all of them when n <= cap):
    a sample that keeps every scan and tile in proportion."""
    return np.linspace(0, n - 1, min(n, cap)).astype(np.int64)


def group_index(
    group: npt.NDArray[np.int64],
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """(N,) index of each row's group among the distinct groups, and each group's row count."""
    _, inv = np.unique(group, return_inverse=True)
    return inv, np.bincount(inv).astype(np.float64)
