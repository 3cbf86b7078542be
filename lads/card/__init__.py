"""Hugging Face dataset card (README.md) of a built variant tree.

`render_card` reads the tree's run.json, manifest.jsonl and pipeline.yaml and fills
dataset_cards/template.md under YAML front matter (style.md §3): the licence is inherited
from the source (never more permissive), sizes and splits come from the manifest.
`validate_card` checks the front matter's enums offline (the Hub's validator is an online
API). The card is part of the tree: the runner writes it before SHA256SUMS, and
`write_card` never touches SHA256SUMS.

Modules: `sources` (source datasets, licences, citations), `tree_facts` (reading the tree,
splits), `front_matter` (Hub enums, YAML front matter), `sections` (markdown sections),
`validate` (offline validation), `render` (render_card, write_card).
"""

from __future__ import annotations

from lads.card.front_matter import (
    ANNOTATION_CREATORS,
    FRONT_MATTER_KEYS,
    LICENSES,
    SIZE_CATEGORIES,
    TAGS,
    TASK_IDS,
    size_category,
)
from lads.card.render import CARD_NAME, card_name, render_card, write_card
from lads.card.sections import NOT_MODELLED, PHYSICS, POINTS_MODE_TEXT, pipeline_stages
from lads.card.sources import (
    CONFIRM,
    DEMO_MARKER,
    NC_SA,
    SOURCES,
    UNKNOWN_SOURCE,
    Source,
    source_info,
)
from lads.card.validate import REQUIRED_SECTIONS, validate_card

__all__ = [
    "ANNOTATION_CREATORS",
    "CARD_NAME",
    "CONFIRM",
    "DEMO_MARKER",
    "FRONT_MATTER_KEYS",
    "LICENSES",
    "NC_SA",
    "NOT_MODELLED",
    "PHYSICS",
    "POINTS_MODE_TEXT",
    "REQUIRED_SECTIONS",
    "SIZE_CATEGORIES",
    "SOURCES",
    "TAGS",
    "TASK_IDS",
    "UNKNOWN_SOURCE",
    "Source",
    "card_name",
    "pipeline_stages",
    "render_card",
    "size_category",
    "source_info",
    "validate_card",
    "write_card",
]
