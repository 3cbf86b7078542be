"""Running many independent fits of one design on several processes.

The stability resamples and the bootstrap refits are independent given their row weights.
Every weight vector is drawn in the parent from the diagnosis' own generator, in order, before
anything is dispatched, so the result does not depend on the number of jobs. Each worker gets
only the rows its fits read (the union of their weighted rows and the held-out rows), in the
original row order, which keeps every sum in the same order as a serial run: the results are
bit-identical for any `jobs`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt
import torch
from threadpoolctl import threadpool_limits

from lads.diagnose.fit.design import Design
from lads.diagnose.fit.likelihood import BASE_NAMES, Model
from lads.diagnose.fit.model import Fit, fit, fit_best

T = TypeVar("T")


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """torch and BLAS on one thread, in the parent and in every worker.

    A fit's arrays are small, so more threads only spin; and a threaded BLAS sums in an
    order that depends on its thread count, which differs between the parent and loky's
    workers (they get cores // jobs): L-BFGS-B's memory products then round differently
    and the results would depend on `jobs`."""
    torch.set_num_threads(1)
    with threadpool_limits(limits=1):
        yield


def restrict(
    d: Design, weights: Sequence[npt.NDArray[np.float64]], extra_rows: npt.NDArray[np.int64]
) -> tuple[Design, list[npt.NDArray[np.float64]], npt.NDArray[np.int64]]:
    """`d` cut to the rows any of `weights` uses plus `extra_rows`, the weights and
    `extra_rows` re-indexed to it."""
    used = np.zeros(len(d), dtype=bool)
    for w in weights:
        used |= w > 0
    used[extra_rows] = True
    keep = np.flatnonzero(used)
    return d.subset(keep), [w[keep] for w in weights], np.searchsorted(keep, extra_rows)


def _chunks(n: int, jobs: int) -> list[range]:
    size = -(-n // max(jobs, 1))
    return [range(i, min(i + size, n)) for i in range(0, n, size)] if n else []


def map_fits(
    task: Callable[..., list[T]],
    d: Design,
    weights: Sequence[npt.NDArray[np.float64]],
    extra_rows: npt.NDArray[np.int64],
    jobs: int,
    *args: Any,
) -> list[T]:
    """[task(design_part, weights_part, extra_rows_part, *args) ...] flattened, in order.

    `task` takes a design, a list of weight vectors and the re-indexed `extra_rows` and
    returns one result per weight vector; it must be a top-level function (pickled by loky).
    """
    parts = []
    for chunk in _chunks(len(weights), jobs):
        part, ws, extra = restrict(d, [weights[i] for i in chunk], extra_rows)
        parts.append((part, ws, extra))
    if jobs <= 1 or len(parts) <= 1:
        with one_thread():
            results = [task(p, ws, ex, *args) for p, ws, ex in parts]
    else:
        from joblib import Parallel, delayed

        results = Parallel(n_jobs=jobs, backend="loky")(
            delayed(task)(p, ws, ex, *args) for p, ws, ex in parts
        )
    return [r for chunk in results for r in chunk]


def fit_warm(
    model: Model,
    d: Design,
    weights: npt.NDArray[np.float64],
    base: npt.NDArray[np.float64],
    previous: Fit | None,
    warm: dict[frozenset[str], Fit] | None = None,
) -> Fit:
    """`fit_best`, or one fit started from `warm`'s vector for the same set of effects.

    A stability resample refits the models of the main selection on a resample of its
    groups: their optimum lies next to the main fit's, so that one start replaces every
    multi-start of the new effect (R0, m, sigma grids) and converges in a few iterations."""
    known = None if warm is None else warm.get(model.key)
    if known is None or known.model.heteroscedastic != model.heteroscedastic:
        return fit_best(model, d, weights, base, previous)
    head = known.theta[: len(BASE_NAMES)]
    x0 = np.concatenate([head] + [known.effect_params(e.label) for e in model.effects])
    return fit(model, d, weights, x0)


def _fit_one(
    part: Design,
    w: npt.NDArray[np.float64],
    model: Model,
    base: npt.NDArray[np.float64],
    previous: Fit | None,
) -> tuple[npt.NDArray[np.float64], float, bool]:
    with one_thread():
        f = fit_best(model, part, w, base, previous)
    return f.theta, f.loss, f.converged


def fit_models(
    models: Sequence[Model],
    d: Design,
    weights: npt.NDArray[np.float64],
    base: npt.NDArray[np.float64],
    previous: Fit | None,
    jobs: int,
    warm: dict[frozenset[str], Fit] | None = None,
) -> list[Fit]:
    """[fit_warm(m, d, weights, base, previous, warm) for m in models], on `jobs` processes.

    Each worker gets only the weighted rows, in order (a fit reads nothing else), so every
    sum runs in the same order as a serial fit and the results are bit-identical. `warm`
    is for the serial resamples (it is not sent to workers)."""
    if jobs <= 1 or len(models) <= 1 or warm is not None:
        with one_thread():
            return [fit_warm(m, d, weights, base, previous, warm) for m in models]
    from joblib import Parallel, delayed

    keep = np.flatnonzero(weights > 0)
    part, w = d.subset(keep), weights[keep]
    # One task a model: their costs differ tenfold (64 ring gains against one exponent), so
    # fixed chunks leave a core idle; loky hands tasks out as workers free up.
    results = Parallel(n_jobs=jobs, backend="loky")(
        delayed(_fit_one)(part, w, m, base, previous) for m in models
    )
    return [Fit(m, *res) for m, res in zip(models, results, strict=True)]
