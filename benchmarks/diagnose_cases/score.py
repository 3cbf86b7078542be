"""Scorer of the concealed-effect benchmark (docs/diagnose.md §6.5): truth.json vs report.json.

`score_case(truth, report, ...)` scores one run, `summarise(scores)` pools runs and checks the
acceptance targets. The scorer reads the truth written by `generate.py` and the tool's
report.json; it never imports the tool.

Rules
-----
* Effect sets: the IDs of report effects with status "claimed" (a missing status counts as
  claimed) against the truth's IDs; C0 (global gain) is ignored on both sides.
* Identification: 1 for an exact match. Otherwise 1/2 when the truth is one of the
  explanations the report leaves open: every ID on which truth and claim differ lies in one
  ambiguity set of the report (an `ambiguity_sets` entry, or an `alternatives` entry read
  as ids + instead_of). For one effect that is a set holding the true and the claimed ID;
  for a pair, a claim {C2, C5} with the set {C1, C5} leaves {C2, C1} open, so the truth
  {C1, C2} earns 1/2, while a claim {C2, C5} with the set {C1, C2} or {C5, C9} does not.
  `exact` (and the summary's identification_pairs_exact) counts exact matches only.
  K14 (truth `accept_ambiguity`): 1 when such a set of two or more IDs lies within the
  accepted sets' union ({C1, C3, C4, C9}); the exact claim {C3} alone then earns 1/2 (a guess
  the ground-only data cannot support). Null cases (no true effect): 1 when nothing is
  claimed.
* False discovery (null cases): any claimed effect other than C0. K19 also scores
  noise_model.kind == "heteroscedastic".
* Parameter error: for each true effect that the report names (claimed, else possible), each
  scalar parameter: |estimate - truth| / (width of the prior range in truth param_ranges);
  start_deg is compared on the circle. Per-ring lists (C4): the median over rings (the
  affected rings for K6) of |d_k - median_j d_j|, d = estimate - truth (a common offset is a
  global gain). C6: the estimate is taken relative to the median of the report's other
  ln_scale_* values (only relative class scales are identified next to C0). Parameters the
  truth marks unidentifiable (saturated retro-reflectors, an i_max nothing reaches) are
  skipped. CI coverage: the truth inside ci95 (same offsets applied); a per-ring list with
  per-ring intervals ([[lo, hi], ...]) counts as one interval worth its covered fraction.
* Recovery ratio: (L_before - L_after) / (L_before - L_oracle), L the mean squared difference
  of ln(I + h) against the real tree over points present in both trees, matched by (relpath,
  row) when the row counts and coordinates agree, else by nearest neighbour within 0.05 m.
  None without a corrected tree or when L_before - L_oracle < max(1e-4, 0.01 L_before).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from lads.sensors.profile import load_profile

SINGLE_CASES = (
    "K1",
    "K2",
    "K3",
    "K4",
    "K5",
    "K6",
    "K7",
    "K8",
    "K9",
    "K10",
    "K11",
    "K15",
    "K16",
    "K17",
    "K20",
)
PAIR_CASES = ("K12", "K13")
NULL_CASES = ("K18", "K19")
AMBIGUITY_CASES = ("K14",)
PROFILES = {"semantickitti": "hdl64e", "nuscenes": "hdl32e"}
MATCH_RADIUS_M = 0.05
CIRCULAR_PARAMS = {"start_deg": 360.0}
TARGETS = {
    "identification_single": (">=", 0.90),
    "identification_pairs": (">=", 0.70),
    "null_false_discovery_rate": ("<=", 0.05),
    "median_parameter_error": ("<=", 0.10),
    "ci_coverage": ("in", (0.85, 0.98)),
    "median_recovery_ratio": (">=", 0.90),
}


def _ids(values: Any) -> set[str]:
    return {str(v) for v in (values or [])} - {"C0"}


def claimed_ids(report: dict[str, Any]) -> set[str]:
    """IDs the report claims (status "claimed", or no status), C0 excluded."""
    return _ids(
        e.get("id")
        for e in report.get("effects", []) or []
        if e.get("status", "claimed") == "claimed"
    )


def ambiguity_sets(report: dict[str, Any]) -> list[set[str]]:
    """Every ambiguity set of the report, alternatives read as ids + instead_of."""
    sets = [_ids(a.get("ids")) for a in report.get("ambiguity_sets", []) or []]
    for alt in report.get("alternatives", []) or []:
        sets.append(_ids(alt.get("ids")) | _ids(alt.get("instead_of")))
    return [s for s in sets if s]


def identification(truth: dict[str, Any], report: dict[str, Any]) -> float:
    """1, 1/2 or 0 (see the module docstring)."""
    true = _ids(e["id"] for e in truth["effects"])
    claimed = claimed_ids(report)
    sets = ambiguity_sets(report)
    accepted = [_ids(a) for a in truth.get("accept_ambiguity", []) or []]
    if accepted:
        union = set().union(*accepted)
        if any(len(s) >= 2 and true <= s <= union and claimed <= s for s in sets):
            return 1.0
        if claimed == true:
            return 0.5
        return 0.0
    if claimed == true:
        return 1.0
    differ = true ^ claimed
    if true and any(differ <= s for s in sets):
        return 0.5
    return 0.0


def _report_entry(report: dict[str, Any], effect: dict[str, Any]) -> dict[str, Any] | None:
    """The report's entry for a true effect: same ID, matching class if any; claimed first."""
    same = [e for e in report.get("effects", []) or [] if e.get("id") == effect["id"]]
    if not same:
        return None
    classes = {c.lower() for c in effect.get("classes", [])}
    if classes:

        def mentions(e: dict[str, Any]) -> bool:
            text = " ".join(
                str(e.get(k, "")) for k in ("class", "classes", "class_name", "label")
            ).lower()
            return any(c in text for c in classes)

        same = sorted(same, key=lambda e: not mentions(e))
    same = sorted(same, key=lambda e: e.get("status", "claimed") != "claimed")
    return same[0]


def _interval(ci: Any) -> tuple[float, float] | None:
    try:
        lo, hi = float(ci[0]), float(ci[1])
    except (TypeError, ValueError, IndexError, KeyError):
        return None
    return (lo, hi) if math.isfinite(lo) and math.isfinite(hi) else None


def parameter_scores(truth: dict[str, Any], report: dict[str, Any]) -> list[dict[str, Any]]:
    """Per true scalar parameter (per-ring lists pooled): error vs prior width and coverage."""
    out = []
    for eff in truth["effects"]:
        entry = _report_entry(report, eff)
        if entry is None:
            continue
        ranges = eff.get("param_ranges") or truth.get("param_ranges", {})
        skip = set(eff.get("unidentifiable_params", []))
        est_params = entry.get("params", {}) or {}
        cis = entry.get("ci95", {}) or {}
        for name, true_value in eff["params"].items():
            if name in skip or name not in ranges or name not in est_params:
                continue
            lo, hi = ranges[name]
            width = float(hi) - float(lo)
            if not width > 0:
                continue
            est = est_params[name]
            ci = cis.get(name)
            row: dict[str, Any] = {"id": eff["id"], "param": name, "status": entry.get("status")}
            if isinstance(true_value, list):
                row.update(_list_error(true_value, est, ci, eff.get("rings"), width))
            else:
                shift = 0.0
                if eff["id"] == "C6":
                    others = [
                        float(v)
                        for k, v in est_params.items()
                        if k.startswith("ln_scale_") and k not in eff["params"]
                    ]
                    shift = float(np.median(others)) if others else 0.0
                row.update(_scalar_error(name, float(true_value), est, ci, shift, width))
            if row.get("error") is not None:
                out.append(row)
    return out


def _scalar_error(
    name: str, true: float, est: Any, ci: Any, shift: float, width: float
) -> dict[str, Any]:
    try:
        value = float(est) - shift
    except (TypeError, ValueError):
        return {"error": None}
    if not math.isfinite(value):
        return {"error": None}
    period = CIRCULAR_PARAMS.get(name)
    diff = value - true
    if period:
        diff = (diff + 0.5 * period) % period - 0.5 * period
    res: dict[str, Any] = {"truth": true, "estimate": value, "error": abs(diff) / width}
    interval = _interval(ci)
    if interval is not None:
        lo, hi = interval[0] - shift, interval[1] - shift
        t = true
        if period:  # put the truth on the interval's turn
            t = lo + (true - lo) % period
        res["covered"] = bool(lo <= t <= hi)
    return res


def _list_error(
    true: list[float], est: Any, ci: Any, rings: list[int] | None, width: float
) -> dict[str, Any]:
    t = np.asarray(true, dtype=np.float64)
    try:
        e = np.asarray(est, dtype=np.float64)
    except (TypeError, ValueError):
        return {"error": None}
    if e.shape != t.shape or not np.isfinite(e).all():
        return {"error": None}
    d = e - t
    offset = float(np.median(d))
    focus = np.asarray(rings, dtype=np.int64) if rings else np.arange(t.size)
    err = float(np.median(np.abs(d - offset)[focus])) / width
    res: dict[str, Any] = {
        "truth": "list",
        "estimate": "list",
        "error": err,
        "offset": offset,
        "elements": int(focus.size),
    }
    try:
        ci_arr = np.asarray(ci, dtype=np.float64)
    except (TypeError, ValueError):
        ci_arr = None
    if ci_arr is not None and ci_arr.shape == (t.size, 2):
        lo, hi = ci_arr[:, 0] - offset, ci_arr[:, 1] - offset
        covered = (lo <= t) & (t <= hi)
        res["covered_fraction"] = float(covered[focus].mean())
    return res


# ----------------------------------------------------------------------------------------
# Trees and the recovery ratio


def read_tree(
    root: Path | str,
) -> dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
    """relpath -> (xyz (N, 3), intensity (N,)) for every scan of a KITTI or nuScenes tree."""
    root = Path(root)
    out = {}
    for path in sorted(root.rglob("*.bin")):
        rel = path.relative_to(root).as_posix()
        cols = 5 if rel.endswith(".pcd.bin") else 4
        raw = np.fromfile(path, dtype="<f4")
        if raw.size % cols:
            continue
        pts = raw.reshape(-1, cols).astype(np.float64)
        out[rel] = (pts[:, :3], pts[:, 3])
    return out


def _find(tree: dict[str, Any], rel: str) -> Any:
    if rel in tree:
        return tree[rel]
    hits = [k for k in tree if k.endswith("/" + rel)]
    return tree[hits[0]] if len(hits) == 1 else None


Matches = dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.bool_]]]


def log_mse(
    other: Path | str, real: Path | str, half_step: float, matches: Matches | None = None
) -> float | None:
    """Mean squared ln(I + h) difference of `other` against `real` over matched points.

    `matches` (relpath -> (xyz of `other`, nearest index, matched)) carries nearest-neighbour
    matches from one call to the next: the simulated, oracle and corrected trees hold the
    same points, and matching each against the real tree again was most of a run's scoring."""
    a, b = read_tree(other), read_tree(real)
    matches = {} if matches is None else matches
    total, count = 0.0, 0
    for rel, (xyz_b, i_b) in b.items():
        hit = _find(a, rel)
        if hit is None or len(i_b) == 0:
            continue
        xyz_a, i_a = hit
        if len(i_a) == len(i_b) and np.allclose(xyz_a, xyz_b, atol=1e-4):
            ia, ib = i_a, i_b
        else:
            known = matches.get(rel)
            if known is None or not np.array_equal(known[0], xyz_a):
                dist, j = cKDTree(xyz_a).query(xyz_b, distance_upper_bound=MATCH_RADIUS_M)
                known = matches[rel] = (xyz_a, j, np.isfinite(dist))
            _, j, ok = known
            ia, ib = i_a[j[ok]], i_b[ok]
        diff = np.log(np.clip(ia, 0.0, None) + half_step) - np.log(
            np.clip(ib, 0.0, None) + half_step
        )
        total += float(np.sum(diff**2))
        count += int(diff.size)
    return total / count if count else None


def recovery(
    truth: dict[str, Any],
    *,
    sim_dir: Path | str,
    real_dir: Path | str,
    corrected_dir: Path | str | None,
    oracle_dir: Path | str,
) -> dict[str, Any]:
    """L_before, L_after, L_oracle and the recovery ratio (None when not defined)."""
    h = 0.5 * load_profile(PROFILES[truth["base"]]).intensity.step
    matches: Matches = {}
    before = log_mse(sim_dir, real_dir, h, matches)
    oracle = log_mse(oracle_dir, real_dir, h, matches)
    after = log_mse(corrected_dir, real_dir, h, matches) if corrected_dir is not None else None
    ratio = None
    if before is not None and oracle is not None and after is not None:
        denom = before - oracle
        if denom >= max(1e-4, 0.01 * before):
            ratio = (before - after) / denom
    return {"L_before": before, "L_after": after, "L_oracle": oracle, "recovery_ratio": ratio}


# ----------------------------------------------------------------------------------------
# One run, many runs


def case_group(case: str) -> str:
    if case in SINGLE_CASES:
        return "single"
    if case in PAIR_CASES:
        return "pairs"
    if case in NULL_CASES:
        return "null"
    return "ambiguity"


def score_case(
    truth: dict[str, Any],
    report: dict[str, Any],
    *,
    sim_dir: Path | str,
    real_dir: Path | str,
    corrected_dir: Path | str | None,
    oracle_dir: Path | str,
) -> dict[str, Any]:
    """Scores of one run (see the module docstring)."""
    true = _ids(e["id"] for e in truth["effects"])
    claimed = claimed_ids(report)
    tp, fp, fn = len(claimed & true), len(claimed - true), len(true - claimed)
    params = parameter_scores(truth, report)
    noise_kind = (report.get("noise_model") or {}).get("kind")
    res: dict[str, Any] = {
        "case": truth["case"],
        "base": truth["base"],
        "mode": truth["mode"],
        "seed": truth["seed"],
        "group": case_group(truth["case"]),
        "truth_ids": sorted(true),
        "claimed_ids": sorted(claimed),
        "possible_ids": sorted(
            _ids(
                e.get("id")
                for e in report.get("effects", []) or []
                if e.get("status") == "possible"
            )
        ),
        "ambiguity_sets": [sorted(s) for s in ambiguity_sets(report)],
        "verdict": report.get("verdict"),
        "identification": identification(truth, report),
        "exact": claimed == true,
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "precision": tp / (tp + fp) if tp + fp else None,
        "recall": tp / (tp + fn) if tp + fn else None,
        "false_discovery": bool(claimed) if not true else None,
        "noise_kind": noise_kind,
        "noise_kind_ok": (noise_kind == truth["noise"]["kind"]) if noise_kind else False,
        "parameters": params,
        "median_parameter_error": (
            float(np.median([p["error"] for p in params])) if params else None
        ),
    }
    res.update(
        recovery(
            truth,
            sim_dir=sim_dir,
            real_dir=real_dir,
            corrected_dir=corrected_dir,
            oracle_dir=oracle_dir,
        )
    )
    res["error"] = None
    return res


def failed_score(truth: dict[str, Any], error: str) -> dict[str, Any]:
    """The score of a run whose tool did not produce a report: nothing identified."""
    return {
        "case": truth["case"],
        "base": truth["base"],
        "mode": truth["mode"],
        "seed": truth["seed"],
        "group": case_group(truth["case"]),
        "truth_ids": sorted(_ids(e["id"] for e in truth["effects"])),
        "claimed_ids": [],
        "identification": 0.0,
        "exact": False,
        "tp": 0,
        "fp": 0,
        "fn": len(_ids(e["id"] for e in truth["effects"])),
        "precision": None,
        "recall": None,
        "false_discovery": None,
        "noise_kind": None,
        "noise_kind_ok": False,
        "parameters": [],
        "median_parameter_error": None,
        "recovery_ratio": None,
        "error": error,
    }


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _met(value: float | None, rule: tuple[str, Any]) -> bool | None:
    if value is None:
        return None
    op, target = rule
    if op == ">=":
        return bool(value >= target)
    if op == "<=":
        return bool(value <= target)
    return bool(target[0] <= value <= target[1])


def summarise(scores: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled rates, per-case identification and the docs/diagnose.md §6.5 targets."""

    def group(name: str) -> list[dict[str, Any]]:
        return [s for s in scores if s.get("group") == name]

    nulls_done = [s for s in group("null") if s.get("error") is None]
    k19 = [s for s in scores if s["case"] == "K19" and s.get("error") is None]
    non_null = [s for s in scores if s.get("group") != "null"]
    params = [p for s in scores if s.get("group") != "null" for p in s.get("parameters", [])]
    covered = [
        float(p.get("covered_fraction", p.get("covered")))
        for p in params
        if "covered" in p or "covered_fraction" in p
    ]  # a list counts as one interval
    recov = [s["recovery_ratio"] for s in scores if s.get("recovery_ratio") is not None]
    tp = sum(s["tp"] for s in non_null)
    fp = sum(s["fp"] for s in non_null)
    fn = sum(s["fn"] for s in non_null)
    per_case: dict[str, dict[str, Any]] = {}
    for s in scores:
        c = per_case.setdefault(s["case"], {"runs": 0, "identification": [], "failed": 0})
        c["runs"] += 1
        c["identification"].append(s["identification"])
        c["failed"] += s.get("error") is not None
    for c in per_case.values():
        c["identification"] = _mean(c["identification"])
    summary: dict[str, Any] = {
        "runs": len(scores),
        "failed": sum(s.get("error") is not None for s in scores),
        "identification_single": _mean([s["identification"] for s in group("single")]),
        "identification_pairs": _mean([s["identification"] for s in group("pairs")]),
        "identification_pairs_exact": _mean([float(s.get("exact", False)) for s in group("pairs")]),
        "identification_k14": _mean([s["identification"] for s in group("ambiguity")]),
        "null_false_discovery_rate": _mean([float(s["false_discovery"]) for s in nulls_done]),
        "k19_noise_model_rate": _mean([float(s["noise_kind_ok"]) for s in k19]),
        "precision": tp / (tp + fp) if tp + fp else None,
        "recall": tp / (tp + fn) if tp + fn else None,
        "median_parameter_error": float(np.median([p["error"] for p in params]))
        if params
        else None,
        "parameters_scored": len(params),
        "ci_coverage": _mean(covered),
        "intervals_scored": len(covered),
        "median_recovery_ratio": float(np.median(recov)) if recov else None,
        "recovery_runs": len(recov),
        "per_case": dict(sorted(per_case.items(), key=lambda kv: int(kv[0][1:]))),
    }
    summary["targets"] = {
        name: {
            "value": summary[name],
            "target": list(rule) if rule[0] != "in" else ["in", list(rule[1])],
            "met": _met(summary[name], rule),
        }
        for name, rule in TARGETS.items()
    }
    return summary
