"""The pointwise generator's input rows in one compiled pass (numba), for inference on a CPU.

`lads.intensity.model.PointGenerator._inputs` builds the same (N, C_in) matrix with torch:
z-scored channels, clamped, then the law's z and the material's learned vector, concatenated
channels last. That takes several passes over a frame's ~120k points; this takes one, with
the same float32 operations in the same order per element (a subtraction, a division, a
clamp, copies), so the rows are the same bits (tests/unit/test_intensity_model.py).
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

F32Array = npt.NDArray[np.float32]


@numba.njit(cache=True, nogil=True)
def _rows(
    raw: F32Array,
    picked: npt.NDArray[np.int64],
    mean: F32Array,
    std: F32Array,
    clamp: np.float32,
    law: F32Array,
    law_input: bool,
    material_channel: int,
    table: F32Array,
    out: F32Array,
) -> None:
    n = raw.shape[1]
    p = picked.shape[0]
    lo, hi = -clamp, clamp
    for c in range(p):  # channel by channel: each source row is read in order
        src = raw[picked[c]]
        mean_c, std_c = mean[c], std[c]
        for i in range(n):
            v = (src[i] - mean_c) / std_c
            out[i, c] = lo if v < lo else (hi if v > hi else v)
    col = p
    if law_input:
        for i in range(n):
            out[i, col] = law[i] if law.shape[0] == n else np.float32(0.0)
        col += 1
    if material_channel >= 0:
        src = raw[material_channel]
        last_row = table.shape[0] - 1
        for i in range(n):
            row = int(min(max(np.rint(src[i]), 0.0), last_row))
            for t in range(table.shape[1]):
                out[i, col + t] = table[row, t]


def input_rows(
    raw: F32Array,
    picked: npt.NDArray[np.int64],
    mean: F32Array,
    std: F32Array,
    clamp: float,
    law: F32Array | None,
    law_input: bool,
    material_channel: int,
    table: F32Array,
) -> F32Array:
    """(N, C_in) float32 inputs of the N points.

    Args:
        raw: (C, N) float32 raw channels of the points (C-contiguous).
        picked: (P,) channel indices the network reads; mean, std: (P,) float32 their
            statistics (0 and 1 for channels not z-scored).
        clamp: z-scored values are clamped to [-clamp, clamp].
        law: (N,) float32 the law's z (None: 0), a column only when law_input.
        material_channel: raw channel of the material index (-1: no material vector).
        table: (M + 1, D) float32 the material vectors (row = index, clamped to the table).
    """
    dims = table.shape[1] if material_channel >= 0 else 0
    out = np.empty((raw.shape[1], len(picked) + int(law_input) + dims), dtype=np.float32)
    _rows(
        raw,
        picked,
        mean,
        std,
        np.float32(clamp),
        np.zeros(0, dtype=np.float32) if law is None else law,
        law_input,
        material_channel,
        table,
        out,
    )
    return out
