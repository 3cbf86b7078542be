"""Reports of an intensity evaluation: `eval.json` (everything) and `eval.md` (tables,
verdicts and targets), written atomically."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lads.files import atomic_write
from lads.intensity import targets
from lads.intensity.eval_metrics import MIN_CELL_POINTS, SUBJECT, best_methods, jsonable
from lads.intensity.evaluate import EvalResult

# Report columns: metric key, header.
REPORT_COLUMNS: tuple[tuple[str, str], ...] = (
    ("mae_encoded", "MAE (encoded)"),
    ("mae_reflectivity", "MAE (refl.)"),
    ("pearson_r", "Pearson r"),
    ("spearman_rho", "Spearman ρ"),
    ("class_ratio_mean_abs_log", "class mean |ln ratio|"),
    ("cell_w1_reflectivity", "cell W1 (refl.)"),
    ("cell_ks", "cell KS"),
    ("global_w1_reflectivity", "global W1 (refl.)"),
    ("global_ks", "global KS"),
    ("retro_contrast_ratio", "retro contrast pred/real"),
)
PLAIN_NAMES = {"mae_reflectivity": "MAE", "cell_w1_reflectivity": "cell W1"}


def write_report(
    result: EvalResult, out_dir: Path, *, title: str, context: Mapping[str, Any]
) -> list[Path]:
    """Write `eval.json` (everything) and `eval.md` (tables and verdicts) into out_dir.

    Args:
        result: from `evaluate`.
        out_dir: created if missing; files are written atomically.
        title: report heading.
        context: what was evaluated (model, data, split, seed...); values JSON-able or str.

    Returns:
        [path of eval.json, path of eval.md].
    """
    out_dir = Path(out_dir)
    payload = {"title": title, "context": jsonable(dict(context)), **result.to_json()}
    json_path, md_path = out_dir / "eval.json", out_dir / "eval.md"
    text = json.dumps(payload, indent=2, allow_nan=False) + "\n"
    atomic_write(json_path, text.encode("utf-8"))
    atomic_write(md_path, markdown_report(result, title=title, context=context).encode("utf-8"))
    return [json_path, md_path]


def markdown_report(result: EvalResult, *, title: str, context: Mapping[str, Any]) -> str:
    """The Markdown text of `write_report`."""
    lines = [f"# {title}", ""]
    lines += [f"- {key}: {jsonable(value)}" for key, value in context.items()]
    lines += [
        f"- held-out frames: {len(result.frame_names)}, points: "
        f"{next(iter(result.pooled.values()))['points']:,}, encoding: {result.encoding}",
        "",
        "## Pooled over all held-out frames",
        "",
        "Best value per column in bold. Reflectivity = encoded intensity / full scale; "
        f"cell = class x range bin x incidence bin with >= {MIN_CELL_POINTS} points; "
        "retro contrast pred/real: 1 is ideal.",
        "",
    ]
    lines += _table(result.pooled)
    lines += ["", *verdicts(result.summary, result.pooled), ""]
    if result.summary.get("targets"):
        lines += ["## Targets (lads.intensity.targets)", ""]
        lines += [*targets.lines(result.summary["targets"]), ""]
    lines += ["## Per frame: MAE (refl.) / cell W1 (refl.)", ""]
    lines.append("| frame | " + " | ".join(result.methods) + " |")
    lines.append("|---|" + "---|" * len(result.methods))
    for frame in result.frame_names:
        row = result.per_frame[frame]
        cells = [
            f"{_fmt(row[m]['mae_reflectivity'])} / {_fmt(row[m]['cell_w1_reflectivity'])}"
            for m in result.methods
        ]
        lines.append(f"| {frame} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _table(pooled: Mapping[str, Mapping[str, Any]]) -> list[str]:
    best = {key: set(best_methods(pooled, key)) for key, _ in REPORT_COLUMNS}
    lines = ["| method | " + " | ".join(h for _, h in REPORT_COLUMNS) + " |"]
    lines.append("|---|" + "---:|" * len(REPORT_COLUMNS))
    for method, row in pooled.items():
        cells = []
        for key, _ in REPORT_COLUMNS:
            text = _fmt(row[key])
            cells.append(f"**{text}**" if method in best[key] else text)
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return lines


def verdicts(summary: Mapping[str, Any], pooled: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Plain-language lines "generator beats X on MAE (a vs b)" from a summary."""
    subject = summary.get("subject")
    if subject is None:
        return [f"No method named '{SUBJECT}': nothing to compare against the baselines."]
    lines = []
    for metric, against in summary["beats"].items():
        name = PLAIN_NAMES.get(metric, metric)
        mine = pooled[subject][metric]
        for other, won in against.items():
            verb = "beats" if won else "does not beat"
            lines.append(
                f"- {subject} {verb} {other} on {name} "
                f"({_fmt(mine)} vs {_fmt(pooled[other][metric])})"
            )
    return lines


def _fmt(value: Any) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.4g}"
