"""One compiled pass for the sums of the fitted law (`lads.intensity.fitted_physics`).

The law's logs (ln R, ln g(theta)) stay numpy's, whose vectorised logarithm a compiled loop
does not reproduce to the bit; what follows them is additions, products and one division
per point, which numba evaluates with the same IEEE operations in the same order as the
numpy expression did, so the values are the same to the bit, without the ten temporary
arrays of a 120k-point frame.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@numba.njit(cache=True, nogil=True)
def law_with_lasers(
    intercept: FloatArray,
    ln_r: FloatArray,
    range_m: FloatArray,
    ln_incidence: FloatArray,
    b1: float,
    b2: float,
    laser: npt.NDArray[np.int64],
    knots: FloatArray,
    curves: FloatArray,
    two_alpha: float,
) -> FloatArray:
    """(N,) a + b1 ln R + b2 R / 10 + ln g + s_l(ln R) - 2 alpha R, in that order of
    operations; s_l blends the two knots of laser l's flattened curve around ln R (clamped
    to the knots), as `FittedPhysics.laser_term` does. `knots` holds two or more."""
    n = intercept.shape[0]
    out = np.empty(n)
    k = knots.shape[0]
    for i in range(n):
        shared = intercept[i] + b1 * ln_r[i] + b2 * range_m[i] / 10.0 + ln_incidence[i]
        x = min(max(ln_r[i], knots[0]), knots[k - 1])
        j = 0  # the last knot <= x, at most the second last (searchsorted right, minus 1)
        while j < k - 2 and knots[j + 1] <= x:
            j += 1
        t = (x - knots[j]) / (knots[j + 1] - knots[j])
        at = laser[i] * k + j
        term = (1.0 - t) * curves[at] + t * curves[at + 1]
        out[i] = shared + term - two_alpha * range_m[i]
    return out


@numba.njit(cache=True, nogil=True)
def oren_nayar_factor(cos_theta: npt.NDArray[Any], a: float, b: float, floor: float) -> FloatArray:
    """(N,) a c + b (1 - c c), c = cos_theta in float64 clipped to [floor, 1] (NaN stays
    NaN, as np.clip leaves it): `fitted_physics.oren_nayar`'s expression, the same bits."""
    out = np.empty(cos_theta.shape[0])
    for i in range(cos_theta.shape[0]):
        c = float(cos_theta[i])
        if c < floor:
            c = floor
        elif c > 1.0:
            c = 1.0
        out[i] = a * c + b * (1.0 - c * c)
    return out
