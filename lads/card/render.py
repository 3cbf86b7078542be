"""Rendering a card from a built tree and writing it as OUT/README.md."""

from __future__ import annotations

import re
from pathlib import Path
from string import Template

from lads.card import sections, tree_facts
from lads.card.front_matter import render_front_matter
from lads.card.kinds import variant_kind
from lads.card.sources import source_info
from lads.files import atomic_write
from lads.resources import card_template

card_name = "README.md"
CARD_NAME = card_name


def render_card(out_root: Path, *, figures: list[str] | tuple[str, ...] = ()) -> str:
    """The card text of a built tree: YAML front matter, then the filled template.

    Args:
        out_root: the built tree (run.json, manifest.jsonl, pipeline.yaml are read).
        figures: image paths relative to out_root to embed (e.g. "figures/range.png").

    Raises:
        ManifestError: run.json or manifest.jsonl is missing or not JSON.
    """
    out_root = Path(out_root)
    run = tree_facts.read_json(out_root / "run.json")
    rows = tree_facts.read_manifest(out_root / "manifest.jsonl")
    pipeline_text = tree_facts.read_text(out_root / "pipeline.yaml")
    src = source_info(run, out_root)
    ok = [r for r in rows if r.get("status") == "ok"]
    splits = tree_facts.splits(run, ok, src)
    kind = variant_kind([name for name, _ in sections.pipeline_stages(pipeline_text)])
    front = render_front_matter(run, src, len(ok), splits, kind)
    fields = sections.fields(run, rows, ok, src, splits, pipeline_text, figures)
    body = Template(card_template().read_text()).substitute(fields)
    return f"---\n{front}---\n\n" + re.sub(r"\n{3,}", "\n\n", body)


def write_card(out_root: Path, *, figures: list[str] | tuple[str, ...] = ()) -> Path:
    """Render the card and write OUT/README.md atomically (tmp + rename); SHA256SUMS is
    left alone (the runner writes the card first, then the checksums)."""
    path = Path(out_root) / card_name
    atomic_write(path, render_card(out_root, figures=figures).encode())
    return path
