"""C11 azimuth-sector blockage or window contamination: + ln(1 - a) in the sector, and the
return probability times (1 - drop_fraction) there.

start_deg is fitted on -360..720 so the sector can wrap, and reported modulo 360.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import torch

from lads.diagnose.config import CONFIG
from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry, training_residual
from lads.diagnose.fit.design import Design

Tensor = torch.Tensor
INFOS = (
    EffectInfo("C11", "azimuth_blockage", "Azimuth-sector blockage / window contamination",
               ("start_deg", "width_deg", "a", "drop_fraction"),
               ((-360.0, 720.0), (2.0, 90.0), (0.0, 0.95), (0.0, 0.95)), (), "both"),
)  # fmt: skip
SECTOR_SOFTNESS_DEG = CONFIG.effects.sector_softness_deg


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on every design, started at the darkest sector of the training rows;
    its dropout part only on paired designs."""
    d = offer.d
    start, width = _darkest_sector(d, offer.train_rows)

    def term(th: Tensor, dd: Design) -> Tensor:
        return torch.log1p(-th[2] * _in_sector(dd.azimuth_deg, th[0], th[1]))

    def survival(th: Tensor, dd: Design) -> Tensor:
        return torch.log1p(-th[3] * _in_sector(dd.azimuth_deg, th[0], th[1]))

    def sector(th: npt.NDArray[np.float64], dd: Design) -> npt.NDArray[np.bool_]:
        offset = np.remainder(dd.azimuth_deg.numpy() - th[0], 360.0)
        return offset < th[1]

    eff = entry(
        INFOS[0],
        ("start_deg", "width_deg", "a", "drop_fraction"),
        [[start, width, 0.3, 0.05]],
        d,
        scalar=[False, True, True, False],
        ln_term=term,
        log_survival=survival if d.paired else None,
        domain=sector,
        exporter=lambda th: {
            "start_deg": float(th[0] % 360.0),
            "width_deg": float(th[1]),
            "a": float(th[2]),
            "drop_fraction": float(th[3]),
        },
    )
    # The sector's edges lie between two azimuth samples, and every bootstrap resample has
    # the same samples: its spread cannot show that, so the CI is never narrower than one
    # sample spacing either side (verdict/intervals.py ci95).
    spacing = azimuth_spacing_deg(d)
    eff.extra["ci_floor"] = {"start_deg": spacing, "width_deg": spacing}
    return [eff]


def _in_sector(az: Tensor, start: Tensor, width: Tensor) -> Tensor:
    """Smooth indicator of azimuth in [start, start + width) (degrees, wrapping)."""
    offset = torch.remainder(az - start, 360.0)
    inside_low = torch.sigmoid(offset / SECTOR_SOFTNESS_DEG)
    inside_high = torch.sigmoid((width - offset) / SECTOR_SOFTNESS_DEG)
    return inside_low * inside_high


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
    rows, r = training_residual(d, train_rows)
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
