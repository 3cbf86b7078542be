"""C10 scan-level automatic gain: - beta (mean ln I_sim of the scan - mean over scans)."""

from __future__ import annotations

from lads.diagnose.effects.base import Effect, EffectInfo, Offer, entry

INFOS = (
    EffectInfo("C10", "scan_auto_gain", "Scan-level AGC", ("beta",), ((0.0, 1.5),), ("C0",),
               "intensity"),
)  # fmt: skip
MIN_SCANS = 5  # a scan-level gain needs scans enough to tell it from noise in one scan


def candidates(offer: Offer) -> list[Effect]:
    """One candidate on designs of at least MIN_SCANS scans."""
    if offer.d.n_scans < MIN_SCANS:
        return []
    return [
        entry(
            INFOS[0], ("beta",), [[0.3]], offer.d, ln_term=lambda th, dd: -th[0] * dd.scan_ln_mean
        )
    ]
