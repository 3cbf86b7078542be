"""Model cards for intensity weights: `python -m lads.intensity.model_card [options] CONFIG...`.

Evaluates each config's weights on its held-out frames (`lads eval-intensity`), then writes
`<weights>.md` beside the weight file: what it was trained on and under which terms, the
command, seed, steps, sha256 and the held-out metrics against every baseline; the held-out
figures go to `<docs>/<name>/`. `make train` runs it on the shipped weights of a checkout
(`--weights-dir lads/intensity/weights --docs docs/intensity --data-root DATA`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from lads.files import atomic_write, sha256_file
from lads.intensity import targets
from lads.intensity.checkpoint import load_model
from lads.intensity.train_config import TrainConfig, load_train_config

TERMS = {
    "semantickitti": "KITTI (CC BY-NC-SA 3.0) and SemanticKITTI labels (CC BY-NC-SA 4.0): "
    "non-commercial",
    "nuscenes-scans": "nuScenes (CC BY-NC-SA 4.0 and the nuScenes Terms of Use): non-commercial",
    "nuscenes": "nuScenes (CC BY-NC-SA 4.0 and the nuScenes Terms of Use): non-commercial",
    "nuscenes-kitti": "nuScenes (CC BY-NC-SA 4.0 and the nuScenes Terms of Use): non-commercial",
    "wads": "WADS (Winter Adverse Driving dataSet), research use: non-commercial",
    "radiate": "RADIATE (CC BY-NC-SA 4.0): non-commercial",
    "synth": "made by `lads synth` in this repository (no third-party terms)",
}
ARCHITECTURE = {
    "pointwise": "pointwise MLP (each point from its own inputs)",
    "unet": "range-image U-Net",
}
GENERATOR_FORM = {
    True: "a correction to the physics law fitted on the target training frames",
    False: "predicts the intensity outright",
}
NO_RAIN = (
    "No real rain recording is available here, so there is no rain style: the rain variant "
    "keeps the physics intensity until a user trains this config with their own rain data."
)


def _domain_line(role: str, spec: Any) -> str:
    lines = []
    for tag, d in spec.members():
        where = d.root or f"{d.frames} frames, seed {d.seed}, sensor {d.sensor}"
        extra = f"; physics weather first: {d.weather}" if d.weather else ""
        split = "; ".join(f"{k}: {', '.join(v)}" for k, v in d.split.items()) or "all frames train"
        name = f"{role} ({tag})" if tag else role
        lines.append(
            f"- {name}: `{d.dataset}` ({where}){extra}; split by place: {split}. "
            f"Terms: {TERMS.get(d.dataset)}."
        )
    return "\n".join(lines)


def _metrics_table(results: dict[str, Any]) -> list[str]:
    lines = []
    # Sorted everywhere: a card reads the same whether scored now or from eval.json.
    for key, res in sorted(results.items()):
        pooled = res.get("pooled", {})
        frames = res["context"]["frames"]
        shown = ", ".join(frames[:6]) + (f" and {len(frames) - 6} more" if len(frames) > 6 else "")
        lines += [
            f"### {key}, {res['context']['split']} split ({shown})",
            "",
            "| method | MAE (encoded) | MAE (reflectivity) | Pearson r | Spearman | "
            "cell W1 (refl.) | cell KS | retro contrast pred / real |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for method, m in sorted(pooled.items()):
            lines.append(
                f"| {method} | {_f(m.get('mae_encoded'))} | {_f(m.get('mae_reflectivity'))} | "
                f"{_f(m.get('pearson_r'))} | {_f(m.get('spearman_rho'))} | "
                f"{_f(m.get('cell_w1_reflectivity'))} | {_f(m.get('cell_ks'))} | "
                f"{_f(m.get('retro_contrast_pred'))} / {_f(m.get('retro_contrast_real'))} |"
            )
        beats = res.get("summary", {}).get("beats", {})
        if beats:
            lines.append("")
            for metric, table in sorted(beats.items()):
                won = sorted(b for b, ok in table.items() if ok)
                lost = sorted(b for b, ok in table.items() if not ok)
                if not lost:
                    lines.append(
                        f"- {metric}: the generator beats every baseline ({', '.join(won)})."
                    )
                else:
                    lines.append(
                        f"- {metric}: the generator beats {', '.join(won) or 'none'}; "
                        f"does not beat {', '.join(lost)}."
                    )
        rows = res.get("summary", {}).get("targets", [])
        if rows:
            lines += ["", "Targets (`lads.intensity.targets`):", "", *targets.lines(rows)]
        lines.append("")
    return lines


def _shares(shares: dict[str, float]) -> str:
    return (
        ", ".join(f"{k} {v:.0%}" for k, v in sorted(shares.items(), key=lambda kv: -kv[1]) if v > 0)
        or "not recorded"
    )


def _decay(cfg: TrainConfig) -> str:
    if cfg.lr_decay_from is None:
        return ""
    return f" falling linearly to 0 from step {round(cfg.lr_decay_from * cfg.steps)}"


def _f(value: Any) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def _held_line(cfg: TrainConfig, held: list[str]) -> list[str]:
    """The card line naming the materials whose vector was held at zero (none: no line)."""
    if not held:
        return []
    return [
        f"- materials with fewer than {cfg.material_min_points} labelled training points, "
        f"answered as never seen (`material_min_points`): {', '.join(held)}"
    ]


def render_card(cfg: TrainConfig, weights: Path, results: dict[str, Any]) -> str:
    model = load_model(weights)
    training = model.meta.training
    lines = [
        f"# Intensity model `{cfg.name}`",
        "",
        cfg.description,
        "",
        f"- file: `{weights.name}`, {weights.stat().st_size / 1e6:.2f} MB, "
        f"sha256 `{sha256_file(weights)}`",
        f"- kind: {cfg.kind}; targets: {', '.join(sorted(model.meta.targets))}; "
        f"generator parameters: {sum(p.numel() for p in model.generator.parameters())}",
        f"- made by: `make train` (`lads train {cfg.name} --data-root DATA`), seed {cfg.seed}, "
        f"batch {cfg.batch}, crop {cfg.crop_width} px, identity points "
        f"{cfg.identity_points or 'from the crops'}, lr {cfg.lr}"
        f"{_decay(cfg)}; of {cfg.steps} steps the "
        f"checkpoint at step {training.get('steps')} scored best on the validation frames "
        "(paired MAE + cell W1) and is this file",
        f"- generator: {ARCHITECTURE[cfg.architecture]}, {GENERATOR_FORM[cfg.residual]}; "
        f"range exponent n = {cfg.range_exponent}; data hash {training.get('data_hash')}",
        *_held_line(cfg, training.get("materials_held", [])),
        f"- loss composition (share of the generator loss, last 100 steps before that "
        f"checkpoint): {_shares(training.get('loss_shares', {}))}; supervised = identity "
        "(labelled real targets), the rest unpaired",
        "",
        "## Training data",
        "",
    ]
    for pair in cfg.pairs:
        lines.append(f"**{pair.key}**")
        lines.append(_domain_line("source", pair.source))
        lines.append(_domain_line("target", pair.target))
        lines.append("")
    lines += [
        "The weights derive from non-commercial data where a target above is non-commercial: "
        "use them under the same terms.",
        "",
    ]
    if cfg.kind == "weather":
        lines += [NO_RAIN, ""]
    lines += [
        "## Test metrics",
        "",
        "Paired: each test frame's geometry and labels are the input; the prediction "
        "is compared with the real intensity of the same points. Cell metrics: "
        "Wasserstein-1 and KS per class x range bin x incidence bin, weighted by count. "
        "Baselines are fitted on the train split only; `bound_in_sample` is fitted on "
        "the test points themselves (an upper bound for per-point features, not a "
        "method). The test frames were scored once, after training, and chose nothing. "
        "Produced by `python -m lads.intensity.model_card` (`lads eval-intensity`).",
        "",
    ]
    if results:
        lines += _metrics_table(results)
    else:
        lines += ["The config has no test frames, so there are no test metrics.", ""]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from lads.intensity.cache import role_split
    from lads.intensity.commands import evaluate_pair

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("configs", nargs="+", help="shipped config names or YAML paths")
    parser.add_argument(
        "--weights-dir",
        type=Path,
        default=None,
        help="folder of <name>.pt (default: each config's output)",
    )
    parser.add_argument(
        "--docs",
        type=Path,
        default=Path("docs/intensity"),
        help="where the held-out figures go (<docs>/<name>/)",
    )
    parser.add_argument("--data-root", type=Path, default=None)
    parser.add_argument(
        "--reuse-eval",
        action="store_true",
        help="render from <docs>/<name>/eval.json instead of scoring the test "
        "frames again (same weights)",
    )
    args = parser.parse_args(argv)
    for name in args.configs:
        cfg = load_train_config(name, data_root=args.data_root)
        weights = (args.weights_dir / f"{cfg.name}.pt") if args.weights_dir else cfg.output_path()
        out_dir = args.docs / cfg.name
        results = {}
        if args.reuse_eval:
            results = json.loads((out_dir / "eval.json").read_text())
        for pair in cfg.pairs if not args.reuse_eval else ():
            if role_split(pair.target, "test", f"pairs.{pair.key}.target"):
                results[pair.key] = evaluate_pair(cfg, pair, str(weights), out_dir)
        atomic_write(out_dir / "eval.json", json.dumps(results, indent=2, sort_keys=True).encode())
        atomic_write(weights.with_suffix(".md"), render_card(cfg, weights, results).encode())
        sys.stdout.write(f"{cfg.name}: card {weights.with_suffix('.md')}, figures {out_dir}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
