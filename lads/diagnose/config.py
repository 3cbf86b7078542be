"""Every threshold of `lads diagnose`, in one place: grouped, with meaning and unit.

The modules that use a value read it from `CONFIG` (under its old module-level name, so the
code reads as before); report.json saves `CONFIG.to_dict()` and its sha256, so a report
says which rules made it. The reasoning behind a value stays beside the code that uses it;
where a value was chosen by looking at benchmark cases, `TUNED_ON` names them (the stories:
benchmarks/results/diagnose_case_notes.md). Values not listed there were set from the
reasoning their module gives; none was fitted on the untouched benchmark seeds
(`benchmarks.diagnose_bench.UNTOUCHED_SEEDS`).

Sizes of the fits themselves (rows per fit, resamples, bootstrap) are run settings, not
thresholds: `lads.diagnose.verdict.analysis.Settings`, also saved in report.json.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True, slots=True)
class TableConfig:
    """Building the beam table: ground planes, edges, pairing, spatial groups.

    Attributes:
        ground_radius_m: ground planes are fitted within this horizontal radius, m.
        ground_seed_percentile: the lowest this % of ground-class points seed the plane.
        ground_inlier_m: inlier band of each plane refit in turn, m.
        ground_band_m: a point within this height of the plane is on the ground, m.
        ground_max_tilt_deg: a steeper fitted ground is taken as level, deg.
        ground_min_points: fewest ground points to fit a plane.
        local_ground_tile_m: tile of the local ground normals, m.
        local_ground_min_points: fewest ground points of a local plane.
        local_ground_min_spread_m: a local plane's support must spread this far (s.d.) in
            its thinner direction, m.
        local_ground_max_tilt_deg: a steeper local ground keeps the image normal, deg.
        edge_jump_m: a range jump between ring neighbours that makes a depth edge, m.
        edge_gap_spacings: missing returns (in median azimuth spacings) that make an edge.
        step_bin_ln: width of the log-spaced bins that find a ring's azimuth step.
        step_band_ln: band around the modal step whose gaps give its median.
        min_step_gaps: fewest gaps to measure a ring's step.
        edge_cap_beams: distances to an edge are capped here, beams.
        group_tile_m: side of the spatial tiles that group rows for held-out tests, m.
        pair_candidates: simulated beams considered per real beam when pairing.
    """

    ground_radius_m: float = 30.0
    ground_seed_percentile: float = 20.0
    ground_inlier_m: tuple[float, ...] = (0.3, 0.3, 0.2, 0.15, 0.1)
    ground_band_m: float = 0.25
    ground_max_tilt_deg: float = 15.0
    ground_min_points: int = 10
    local_ground_tile_m: float = 5.0
    local_ground_min_points: int = 15
    local_ground_min_spread_m: float = 0.5
    local_ground_max_tilt_deg: float = 15.0
    edge_jump_m: float = 1.0
    edge_gap_spacings: float = 4.0
    step_bin_ln: float = 0.02
    step_band_ln: float = 0.15
    min_step_gaps: int = 20
    edge_cap_beams: float = 10.0
    group_tile_m: float = 10.0
    pair_candidates: int = 4


@dataclass(frozen=True, slots=True)
class LocalizeConfig:
    """Binning the mismatch and testing bins (docs/diagnose.md §3).

    Attributes:
        range_edges_m: range bin edges, m.
        cos_bins: bins of the incidence cosine over [0, 1].
        azimuth_sector_deg: azimuth bin width, deg.
        edge_edges_beams: bin edges of the distance to a depth edge, beams.
        min_bin_share: a bin enters tests and effect sizes with at least this share of rows.
        min_effect_groups: ... and this many spatial groups for an effect size.
        min_test_groups: ... and this many groups for the omnibus test.
        min_test_events: ... and, for 0/1 outcomes, this many expected events.
        min_compare_rows: rows both sides of a ground vs non-ground comparison need.
        agree_share: share of bins whose sign must agree for a pattern to be stated.
        q_threshold: false discovery rate of the bin tests.
        min_heatmap_rows: rows a heat-map cell needs to be drawn.
        bootstrap: group-bootstrap resamples of the localisation statements.
    """

    range_edges_m: tuple[float, ...] = (0.9, 2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 120.0)
    cos_bins: int = 10
    azimuth_sector_deg: float = 10.0
    edge_edges_beams: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0, 5.0, 10.0, math.inf)
    min_bin_share: float = 0.01
    min_effect_groups: int = 3
    min_test_groups: int = 10
    min_test_events: int = 20
    min_compare_rows: int = 20
    agree_share: float = 2.0 / 3.0
    q_threshold: float = 0.05
    min_heatmap_rows: int = 20
    bootstrap: int = 100


@dataclass(frozen=True, slots=True)
class DesignConfig:
    """The design matrix: what a stored value means and which rows a fit sees.

    Attributes:
        cos_floor: ln cos(theta) of grazing returns is taken at this cosine at least.
        edge_near_beams: a return this close to a depth edge (beams) is "at an edge".
        low_steps: below this many quantisation steps a stored value is an interval.
        zero_fit_steps: values at most this many steps above 0 get their power imputed.
        zero_fit_min_rows: fewest rows above the zero interval to fit the simulation's law.
        zero_quantiles: quantiles of the imputed power within the zero interval.
        tobit_max_rows: rows of the censored fit of the simulation's own law.
        clip_ratio: the top stored value holds this many times the rows of the step below
            it to be the encoding's clip.
        clip_min_share: ... and this share of all returns.
        clip_min_rows: ... and at least this many rows.
    """

    cos_floor: float = 0.05
    edge_near_beams: float = 2.0
    low_steps: int = 10
    zero_fit_steps: int = 2
    zero_fit_min_rows: int = 200
    zero_quantiles: int = 16
    tobit_max_rows: int = 20_000
    clip_ratio: float = 5.0
    clip_min_share: float = 0.002
    clip_min_rows: int = 20


@dataclass(frozen=True, slots=True)
class EffectsConfig:
    """The candidate effects (docs/diagnose.md §1).

    Attributes:
        min_class_rows: fewest rows of a class for a per-class term.
        min_confined_rows: fewest rows of a class-confined effect (glossy, retro).
        ridge: ridge penalty of the per-ring and per-class parameters, per nat.
        sector_softness_deg: softness of a blockage sector's edges, deg.
        few_rings_level: family-wise level at which a ring's training residual stands out.
        max_few_rings: most rings of the few-ring gain (more is the full C4's job).
        odd_ring_rounds: rounds of choosing odd rings.
        range_bins: log-spaced range bins within which rings are compared.
        range_bin_top_m: top of those bins, m.
    """

    min_class_rows: int = 200
    min_confined_rows: int = 50
    ridge: float = 1e-3
    sector_softness_deg: float = 0.5
    few_rings_level: float = 0.05
    max_few_rings: int = 8
    odd_ring_rounds: int = 4
    range_bins: int = 24
    range_bin_top_m: float = 120.0


@dataclass(frozen=True, slots=True)
class FitConfig:
    """The optimiser (L-BFGS-B) and what counts as a parameter at its bound.

    Attributes:
        max_iter: iterations per fit.
        ftol: relative loss change to stop at.
        maxcor: L-BFGS memory (pairs).
        bound_tolerance: within this share of its range from a bound, a parameter is there.
        bound_nudge: share of the range a bound test moves the parameter inward.
        flat_loss: nats per row below which moving it costs nothing (the bound does not bind).
    """

    max_iter: int = 150
    ftol: float = 1e-7
    maxcor: int = 30
    bound_tolerance: float = 0.01
    bound_nudge: float = 0.05
    flat_loss: float = 1e-6


@dataclass(frozen=True, slots=True)
class SelectConfig:
    """Held-out selection of effects (docs/diagnose.md §5.5).

    Attributes:
        k_max: most effects selected.
        min_gain_nats: held-out NLL gain per row below which an effect is not named, nats.
        baseline_share: ... nor below this share of the baseline's held-out deviance.
        z_accept: held-out directional score needed to accept, cluster SEs.
        z_resample: the bar of the stability resamples, cluster SEs.
        min_support_groups: fewest held-out groups holding a class-confined effect's rows.
        screen_rows: training rows of the screening fits of a forward step.
        crossfit_below_groups: a class in fewer held-out groups is also cross-fitted.
        crossfit_folds: folds of that cross-fit.
        shortlist: candidates refitted on all rows after screening.
        shortlist_confined: ... plus this many class-confined ones.
        claim_frequency: share of resamples that must choose an effect to claim it.
        possible_frequency: share that makes it "possible".
        test_share: share of spatial groups held out as the test split.
        validation_share: share of the rest held out for validation.
    """

    k_max: int = 4
    min_gain_nats: float = 0.002
    baseline_share: float = 0.005
    z_accept: float = 3.0
    z_resample: float = 2.0
    min_support_groups: int = 4
    screen_rows: int = 5000
    crossfit_below_groups: int = 20
    crossfit_folds: int = 4
    shortlist: int = 4
    shortlist_confined: int = 2
    claim_frequency: float = 0.7
    possible_frequency: float = 0.3
    test_share: float = 0.2
    validation_share: float = 0.5


@dataclass(frozen=True, slots=True)
class VerdictConfig:
    """Ambiguity rules, noise verdicts and what a run needs at all.

    Attributes:
        long_range_band_m: range band that tells attenuation from a range exponent, m.
        long_range_min_share: share of rows in that band for attenuation to be named.
        ground_only_share: off-ground share of intensity rows below which the ground's
            range-like terms are one ambiguity set.
        noise_min_slope: slope of ln sigma per ln R (or ln I) that matters.
        point_noise_min_slope: the same for the neighbour-difference point noise.
        z_test: test-group gain (cluster SEs) that makes unstable effects "ambiguous".
        min_rows: fewest comparable beams to fit.
        min_groups: fewest spatial groups to fit.
        paired_share_warn: share of beams returning in both paired trees below which the
            report warns that the trees may not be the same scenes.
    """

    long_range_band_m: tuple[float, float] = (30.0, 120.0)
    long_range_min_share: float = 0.05
    ground_only_share: float = 0.05
    noise_min_slope: float = 0.1
    point_noise_min_slope: float = 0.25
    z_test: float = 3.0
    min_rows: int = 2000
    min_groups: int = 10
    paired_share_warn: float = 0.5


@dataclass(frozen=True, slots=True)
class PointNoiseConfig:
    """Point noise from neighbouring returns (docs/diagnose.md E11).

    Attributes:
        nu: degrees of freedom of the Student t of pair differences.
        max_gap_spacings: neighbours at most this many azimuth spacings apart.
        max_dr_share: |R_i - R_j| at most this share of R (plus max_dr_m).
        max_dr_m: ... plus this, m.
        min_pairs: fewest pairs to fit.
        min_bin_pairs: fewest pairs of a range bin of the figure.
        fit_pairs: pairs the fit uses at most.
    """

    nu: float = 4.0
    max_gap_spacings: float = 2.5
    max_dr_share: float = 0.02
    max_dr_m: float = 0.05
    min_pairs: int = 500
    min_bin_pairs: int = 50
    fit_pairs: int = 200_000


@dataclass(frozen=True, slots=True)
class DiagnoseConfig:
    """All thresholds of `lads diagnose`, by stage of the method."""

    table: TableConfig = field(default_factory=TableConfig)
    localize: LocalizeConfig = field(default_factory=LocalizeConfig)
    design: DesignConfig = field(default_factory=DesignConfig)
    effects: EffectsConfig = field(default_factory=EffectsConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    select: SelectConfig = field(default_factory=SelectConfig)
    verdict: VerdictConfig = field(default_factory=VerdictConfig)
    point_noise: PointNoiseConfig = field(default_factory=PointNoiseConfig)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready values (tuples as lists, an infinite bin edge as the string "inf")."""
        return {
            group: {k: _jsonable(v) for k, v in values.items()}
            for group, values in asdict(self).items()
        }

    def sha256(self) -> str:
        """Hash of `to_dict()` (sorted keys): equal hashes, equal rules."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()


def _jsonable(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_jsonable(v) for v in value]
    return "inf" if isinstance(value, float) and math.isinf(value) else value


CONFIG = DiagnoseConfig()

# Values chosen by looking at benchmark cases (group.field -> what was looked at).
TUNED_ON: dict[str, str] = {
    "select.baseline_share": "the whole-scan CI subset: a share of the NLL instead kept a weak "
    "ring (K6) out on KITTI cases",
    "fit.maxcor": "per-ring and per-class fits of the benchmark cases that ran into max_iter "
    "with scipy's default memory of 10",
    "fit.ftol": "the slow per-ring fits of the benchmark cases (halved their iterations)",
}
