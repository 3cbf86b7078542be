"""Whole groups (tiles of a scan) to train / validation / test, and the fit weights that
subsample a group set's rows."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lads.diagnose.config import CONFIG
from lads.diagnose.fit.design import Design

TEST_SHARE = CONFIG.select.test_share
VALIDATION_SHARE = CONFIG.select.validation_share


@dataclass(frozen=True)
class Split:
    """Row indices of the train, validation and test groups (30/50/20 of the groups).

    A fit reads at most `Settings.fit_rows` rows, which 30 % of the groups supply many times
    over, while the cluster SE of a held-out gain shrinks with the number of validation
    groups: 50 % of them there rather than docs/diagnose.md's 20 % halves the variance of every
    accept/reject decision at no cost in fit quality."""

    train: npt.NDArray[np.int64]
    validation: npt.NDArray[np.int64]
    test: npt.NDArray[np.int64]
    n_groups: dict[str, int]


def split_groups(d: Design, rng: np.random.Generator) -> Split:
    """Assign whole groups to train / validation / test."""
    groups = np.unique(d.group)
    order = rng.permutation(groups)
    n = len(order)
    n_test = max(1, int(round(TEST_SHARE * n)))
    n_val = max(1, int(round(VALIDATION_SHARE * n)))
    test_g, val_g = order[:n_test], order[n_test : n_test + n_val]
    in_test = np.isin(d.group, test_g)
    in_val = np.isin(d.group, val_g)
    rows = np.arange(len(d))
    return Split(
        train=rows[~in_test & ~in_val],
        validation=rows[in_val],
        test=rows[in_test],
        n_groups={"train": n - n_test - n_val, "validation": n_val, "test": n_test},
    )


def fit_weights(
    n: int,
    rows: npt.NDArray[np.int64],
    cap: int,
    rng: np.random.Generator,
    multiplicity: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]:
    """(n,) weights: 1 on at most `cap` of `rows` (a uniform subsample), else 0.

    `multiplicity` (n,) scales them (group bootstrap counts). Subsampling rows keeps every
    group represented while bounding the cost of a fit."""
    chosen = rows if len(rows) <= cap else rng.choice(rows, cap, replace=False)
    w = np.zeros(n)
    w[chosen] = 1.0
    if multiplicity is not None:
        w *= multiplicity
    return w
