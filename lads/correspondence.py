"""Point correspondence between a source frame and its transformed frame.

Weather removes beams (lost) and replaces target returns by particle returns; the writer
offers two ways to put that on disk (docs/output_tree.md):

- physical: the transformed points as they are; labels follow each point's source beam and
  particle returns get the particle label.
- aligned: N and order of the source; lost beams sit at the sensor origin with intensity 0,
  labels are the source labels unchanged.
- resampled: a sensor transfer's output (`lads.transfer`): every point is a beam of the
  target sensor, RESAMPLED from a surface of the source scan or of a scan of its window;
  labels follow the surface hit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from lads.frame import Frame
from lads.physics.result import Outcome

# The writer's point-correspondence modes (`writer.points` of a pipeline, `points_mode` of
# run.json); docs/output_tree.md.
POINT_MODES = ("physical", "aligned", "resampled")


def label_fits(label: int, dtype: np.dtype) -> bool:
    """Whether the particle class `label` is a value of integer labels of `dtype` (a cast
    would wrap -1 to 4294967295 in uint32, or 300 to a real class in uint8); any value fits
    a non-integer dtype."""
    if not np.issubdtype(dtype, np.integer):
        return True
    info = np.iinfo(dtype)
    return info.min <= int(label) <= info.max


def physical(
    out: Frame, particle_label: int
) -> tuple[Frame, npt.NDArray[np.int64], npt.NDArray[np.uint8]]:
    """Frame to encode in physical mode, with per output point (source_index, outcome).

    Particle returns get `particle_label` as class with instance 0; extra label arrays
    (e.g. Voxelscape orig_labels) get 0 there.
    """
    particle = out.outcome == Outcome.PARTICLE
    labels = out.labels
    extras = out.extra_labels
    if particle.any():
        if labels is not None:
            labels = labels.copy()
            labels[particle] = particle_label
        extras = {}
        for role, values in out.extra_labels.items():
            values = values.copy()
            values[particle] = 0
            extras[role] = values
    frame = replace(out, labels=labels, extra_labels=extras)
    return frame, out.source_index, out.outcome


def aligned(
    source: Frame, out: Frame
) -> tuple[Frame, npt.NDArray[np.int64], npt.NDArray[np.uint8]]:
    """Frame to encode in aligned mode (source N and order), with (source_index, outcome).

    Lost beams: x, y, z and intensity 0, other columns (ring) from the source, the paper's
    release convention. Labels and extra labels are the source's, unchanged.
    """
    n = source.n_source
    points = np.array(source.points, dtype=np.float32, copy=True)
    points[out.source_index] = out.points
    points[out.lost_index, :4] = 0.0
    outcome = np.full(n, Outcome.LOST, dtype=np.uint8)
    outcome[out.source_index] = out.outcome
    frame = replace(
        source,
        points=points,
        source_index=np.arange(n, dtype=np.int64),
        outcome=outcome,
        lost_index=out.lost_index,
    )
    return frame, np.arange(n, dtype=np.int64), outcome


def outcome_counts(
    source_points: int,
    outcome: npt.NDArray[np.uint8],
    lost: int,
    source_index: npt.NDArray[np.int64] | None = None,
) -> dict[str, int]:
    """Point counts for the manifest: source, output, kept, attenuated, particle, lost, and
    (dual-return trees only) second_returns, the output points that are a beam's second,
    (sensor transfers only) resampled, the target's beams, and (motion-distorted sweeps
    only) displaced, the returns reported at another position."""
    found = np.bincount(outcome, minlength=len(Outcome))
    counts = {
        "source": int(source_points),
        "output": int(outcome.size),
        "kept": int(found[Outcome.KEPT]),
        "attenuated": int(found[Outcome.ATTENUATED]),
        "particle": int(found[Outcome.PARTICLE]),
        "lost": int(lost),
    }
    if found[Outcome.RESAMPLED]:
        counts["resampled"] = int(found[Outcome.RESAMPLED])
    if found[Outcome.DISPLACED]:
        counts["displaced"] = int(found[Outcome.DISPLACED])
    # A transfer's beams may share a source return (two beams on one surfel): not a dual return.
    dual = source_index is not None and not found[Outcome.RESAMPLED]
    second = int(np.count_nonzero(np.diff(source_index) == 0)) if dual else 0  # type: ignore[arg-type]
    if second:
        counts["second_returns"] = second
    return counts
