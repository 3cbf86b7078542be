"""report.json and report.md of `lads diagnose` (docs/diagnose.md §1 and §5.6)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lads.diagnose.effects.catalogue import CATALOGUE
from lads.diagnose.verdict.analysis import Diagnosis, EffectReport
from lads.files import atomic_write
from lads.jsontypes import json_types

SCHEMA_VERSION = 1


def _classes(r: EffectReport) -> list[str]:
    """The classes an effect acts on; for a wet surface those fitted wet on most of it."""
    names = r.effect.extra.get("wet_share_names")
    classes = list(r.effect.extra["classes"])
    if names is None:
        return classes
    return [c for c, n in zip(classes, names, strict=True) if r.params.get(n, 0.0) >= 0.5]


def build_report(
    dg: Diagnosis, context: dict[str, Any], localization: dict[str, Any], figures: list[str]
) -> dict[str, Any]:
    """The report.json document (JSON types only, no NaN)."""
    effects = []
    for r in dg.effects:
        effects.append(
            {
                "id": r.effect.info.id,
                "key": r.effect.info.key,
                "name": r.effect.info.name,
                "label": r.effect.label,
                "class": r.effect.class_name,
                "params": r.params,
                "ci95": r.ci95,
                "selection_frequency": r.selection_frequency,
                "status": r.status,
                "unidentified_params": r.unidentified,
                **({"classes": _classes(r)} if "classes" in r.effect.extra else {}),
            }
        )
    trace = [s.to_json() for s in dg.selection.trace]
    doc = {
        "schema_version": SCHEMA_VERSION,
        "verdict": dg.verdict,
        "verdict_reasons": dg.reasons,
        **context,
        "localization": localization.get("statements", []),
        "effects": effects,
        "possible_effects": dg.possible,
        "alternatives": dg.alternatives,
        "ambiguity_sets": dg.ambiguity_sets,
        "noise_model": dg.noise_model,
        "heldout": dg.heldout,
        "split": {
            "groups": dg.split.n_groups,
            "rows": {
                "train": int(len(dg.split.train)),
                "validation": int(len(dg.split.validation)),
                "test": int(len(dg.split.test)),
            },
        },
        "selection_trace": trace,
        # The held-out NLL gain (nats/row) an accepted effect had to beat (select.gain_floor).
        "gain_floor_nats": dg.selection.floor,
        "selection_frequency": dg.frequencies,
        # C0 alone (the `before` model) and C0 fitted jointly with the effects (`after`).
        "baseline": {
            "id": "C0",
            "key": "global_gain",
            "ln_gain": float(dg.selection.baseline.theta[0]),
            "ln_gain_with_effects": float(dg.final.theta[0]),
        },
        "figures": figures,
        "localization_detail": localization,
    }
    return json_types(doc)


def write_report(doc: dict[str, Any], out: Path) -> None:
    """Write report.json and report.md into `out` atomically."""
    atomic_write(out / "report.json", (json.dumps(doc, indent=2) + "\n").encode())
    atomic_write(out / "report.md", markdown(doc).encode())


def _fmt(v: Any) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        if len(v) > 6:
            return f"[{len(v)} values]"
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def markdown(doc: dict[str, Any]) -> str:
    """A person's summary of the report (the template sentence of §5.6 per effect)."""
    lines = [
        *_md_header(doc),
        *_md_localization(doc),
        *_md_effects(doc),
        *_md_alternatives(doc),
        *_md_noise_model(doc),
        *_md_heldout(doc),
        *_md_selection_trace(doc),
    ]
    if doc.get("figures"):
        lines += ["", "## Figures", ""] + [f"![{f}]({f})" for f in doc["figures"]]
    return "\n".join(lines) + "\n"


def _md_header(doc: dict[str, Any]) -> list[str]:
    """Title, inputs, size and verdict."""
    lines = ["# lads diagnose report", ""]
    lines.append(
        f"- simulation: `{doc.get('sim_root')}`; real: `{doc.get('real_root')}`; "
        f"source {doc.get('source')}, {doc.get('mode')}, seed {doc.get('seed')}"
    )
    lines.append(
        f"- beams: {doc.get('rows')}, scans: {doc.get('scans')}; sensor "
        f"{doc.get('sensor', {}).get('profile')}"
    )
    lines.append(
        f"- **verdict: {doc['verdict']}**"
        + (f" ({'; '.join(doc['verdict_reasons'])})" if doc["verdict_reasons"] else "")
    )
    lines += [f"- **warning:** {w}" for w in doc.get("warnings") or []]
    return lines


def _md_localization(doc: dict[str, Any]) -> list[str]:
    """Where the simulation and the real data differ."""
    lines = ["", "## Where simulation and reality differ", ""]
    for s in doc["localization"] or []:
        lines.append(f"- {s.get('text')}")
    if not doc["localization"]:
        lines.append("- no feature shows a significant difference (BH q < 0.05)")
    return lines


def _md_effects(doc: dict[str, Any]) -> list[str]:
    """The selected effects with their parameters, and the possible ones."""
    lines = ["", "## Missing physics", ""]
    if not doc["effects"]:
        lines.append(
            "None: no catalogue effect improved the held-out fit by more than three "
            "cluster standard errors."
        )
    for e in doc["effects"]:
        params = ", ".join(
            f"{k} = {_fmt(v)} {_fmt(e['ci95'].get(k))}" for k, v in e["params"].items()
        )
        where = f" on {e['class']}" if e.get("class") else ""
        if e.get("unidentified_params"):
            params += (
                f" (not informed by the data: {', '.join(e['unidentified_params'])}; "
                "the interval is the catalogue range)"
            )
        lines.append(
            f"- **{e['id']} {e['name']}** (`{e['key']}`){where}: {params}; selected "
            f"in {e['selection_frequency']:.0%} of resamples ({e['status']})."
        )
    for p in doc.get("possible_effects", []):
        lines.append(
            f"- possible: {p['id']} `{p['key']}` ({p['label']}), selected in "
            f"{p['selection_frequency']:.0%} of resamples"
        )
    return lines


def _md_alternatives(doc: dict[str, Any]) -> list[str]:
    """Ambiguity sets and alternatives that fit as well (nothing if none)."""
    lines: list[str] = []
    if doc["ambiguity_sets"] or doc["alternatives"]:
        lines += ["", "## Alternatives that fit as well", ""]
        for s in doc["ambiguity_sets"]:
            names = ", ".join(f"{i} {CATALOGUE[i].name}" for i in s["ids"])
            lines.append(f"- cannot be separated: {names} ({s['reason']})")
        for a in doc["alternatives"]:
            lines.append(
                f"- {a['id']} `{a['key']}` instead of {', '.join(a['instead_of'])}: "
                f"held-out loss {a['delta_loss']:+.4f} (SE {a['se']:.4f}); separate "
                f"with {a['separating_data']}"
            )
    return lines


def _md_noise_model(doc: dict[str, Any]) -> list[str]:
    """The fitted noise model and the point noise."""
    nm = doc["noise_model"]
    lines = [
        "",
        "## Noise model",
        "",
        f"- {nm['kind']}: sigma(ln I) = {nm['sigma_ln_i']:.3f}, range slope "
        f"{nm['range_slope']:+.3f}, level slope {nm['level_slope']:+.3f}; return "
        f"probability {nm['return_probability']:.3f} (all residual spread: point "
        "noise and each surface's own reflectance)",
    ]
    pn = nm.get("point_noise") or {}
    if "range_slope" in pn:
        z = pn["heldout_gain_nats"]["z"]
        lines.append(
            f"- point noise ({pn['pairs']} neighbour pairs, differences within one "
            f"surface): {pn['kind']}, sigma(ln I) ~ {pn['sigma_ln_i_if_gaussian']:.3f}"
            f", range slope {pn['range_slope']:+.3f} {_interval(pn['range_slope_ci95'])}"
            f", level slope {pn['level_slope']:+.3f} "
            f"{_interval(pn['level_slope_ci95'])}; held-out z {z:.1f}"
        )
    elif pn:
        lines.append(f"- point noise: {pn['kind']} ({pn.get('reason', '')})")
    return lines


def _md_heldout(doc: dict[str, Any]) -> list[str]:
    """The held-out test groups' table."""
    h = doc["heldout"]
    lines = [
        "",
        f"## Held-out test groups ({h['groups']} groups, {h['rows']} beams)",
        "",
        "| model | RMSE ln I | MAE ln I | R² ln I | dropout Brier | dropout log-loss |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name in ("simulation", "before", "after"):
        m = h.get(name) or {}
        lines.append(
            f"| {name} | {_fmt(m.get('rmse_ln_i'))} | {_fmt(m.get('mae_ln_i'))} | "
            f"{_fmt(m.get('r2_ln_i'))} | {_fmt(m.get('dropout_brier'))} | "
            f"{_fmt(m.get('dropout_log_loss'))} |"
        )
    lines += [
        "",
        "`simulation`: ln I_sim as is; `before`: baseline (global gain, noise, "
        "constant return rate); `after`: with the selected effects.",
        "",
    ]
    return lines


def _md_selection_trace(doc: dict[str, Any]) -> list[str]:
    """The forward selection, step by step."""
    lines = [
        "## Selection trace",
        "",
        "Δ held-out loss: mean NLL gain per beam on the validation groups, with its "
        "cluster SE; z: the held-out directional score in SEs, the acceptance test.",
        "",
        "| step | candidate | Δ held-out loss | SE | z | ΔBIC | at bound | accepted |",
        "|---:|---|---:|---:|---:|---:|---|---|",
    ]
    for s in doc["selection_trace"]:
        lines.append(
            f"| {s['step']} | {s['candidate']} | {s['delta_loss']:.4f} | {s['se']:.4f}"
            f" | {s.get('z', float('nan')):.1f} | {s['delta_bic']:.1f} | {s['at_bound']}"
            f" | {s['accepted']} |"
        )
    return lines


def _interval(ci: list[float]) -> str:
    return f"[{ci[0]:+.3f}, {ci[1]:+.3f}]"
