"""The sizes of one diagnosis: rows, resamples, bootstrap refits, effects and jobs."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Settings:
    """Effort knobs of a diagnosis.

    Attributes:
        fit_rows: training rows per fit (a uniform subsample; groups all stay represented).
        resamples: group-bootstrap reruns of the selection (stability, §5.5 step 7).
        selection_rows: validation rows the main selection scores on (every k-th; all of
            them when fewer). Its SEs are cluster SEs: rows of one 10 m tile share their
            surfaces, so rows beyond a few hundred thousand add little but time.
        resample_rows: the same for the resamples, which ask only whether the main
            selection's effects win again (fewer rows suffice).
        bootstrap: group-bootstrap refits of the final model (95 % percentile CIs).
        k_max: most effects selected.
        jobs: processes for the resamples and bootstrap refits (results do not depend on it).

    fit_rows must leave every one of 64 per-ring gains several surfaces, or the selection
    flips between resamples. How these row counts were chosen, and on which cases:
    benchmarks/results/diagnose_case_notes.md.
    """

    fit_rows: int = 15000
    resamples: int = 10
    resample_rows: int = 60_000
    selection_rows: int = 200_000
    bootstrap: int = 40
    k_max: int = 4
    jobs: int = 2
