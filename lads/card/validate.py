"""Offline validation of a card: its front matter against the Hub's enums (licence ids,
size categories, annotation creators, tasks, split names) and its required sections."""

from __future__ import annotations

import re
from typing import Any

import yaml

from lads.card.front_matter import (
    ANNOTATION_CREATORS,
    FRONT_MATTER_KEYS,
    LICENSES,
    SIZE_CATEGORIES,
    TASK_IDS,
    size_category,
)

REQUIRED_SECTIONS = (
    "Dataset Details", "Uses", "Dataset Structure", "Generation",
    "Physical model and limitations", "Verification", "Bias, Risks, and Limitations", "Citation",
)  # fmt: skip


def validate_card(text: str) -> list[str]:
    """Problems of a card's front matter and sections, checked offline against the Hub's
    enums (licence ids, size categories, annotation creators, tasks, split names)."""
    m = re.match(r"^---\n(.*?\n)---\n", text, re.S)
    if not m:
        return ["no YAML front matter ('---' line, YAML, '---' line) at the top"]
    try:
        meta = yaml.safe_load(m.group(1))
    except yaml.YAMLError as exc:
        return [f"front matter is not valid YAML ({exc})"]
    if not isinstance(meta, dict):
        return ["front matter is not a mapping"]
    problems = [f"unknown front-matter key {k!r}" for k in meta if k not in FRONT_MATTER_KEYS]
    problems += _check_license(meta)
    problems += _check_enums(meta)
    problems += _check_dataset_info(meta)
    body = text[m.end() :]
    problems += [
        f"section '## {s}' missing" for s in REQUIRED_SECTIONS if f"\n## {s}" not in "\n" + body
    ]
    return problems


def _check_license(meta: dict[str, Any]) -> list[str]:
    lic = meta.get("license")
    if lic not in LICENSES:
        return [f"license {lic!r} is not a Hub licence id"]
    problems = []
    if lic == "other" and not (meta.get("license_name") and meta.get("license_link")):
        problems.append("license 'other' needs license_name and license_link")
    name = meta.get("license_name")
    if name is not None and not re.fullmatch(r"[a-z0-9][a-z0-9.-]*", str(name)):
        problems.append(f"license_name {name!r} must be a lowercase id (a-z, 0-9, '-', '.')")
    return problems


def _check_enums(meta: dict[str, Any]) -> list[str]:
    problems = []
    checks = (
        ("annotations_creators", ANNOTATION_CREATORS),
        ("size_categories", set(SIZE_CATEGORIES) | {"other"}),
        ("task_categories", set(TASK_IDS)),
    )
    for key, allowed in checks:
        values = meta.get(key, [])
        if not isinstance(values, list) or not values:
            problems.append(f"{key} must be a non-empty list")
            continue
        problems += [
            f"{key}: {v!r} is not one of {sorted(allowed)}" for v in values if v not in allowed
        ]
    ids = set().union(*(TASK_IDS.get(c, set()) for c in meta.get("task_categories") or []))
    problems += [
        f"task_ids: {t!r} does not belong to the task_categories"
        for t in meta.get("task_ids") or []
        if t not in ids
    ]
    for s in meta.get("source_datasets") or []:
        if not re.fullmatch(r"original|extended(\|[\w.-]+)?", str(s)):
            problems.append(f"source_datasets: {s!r} is not 'original' or 'extended|<id>'")
    if not isinstance(meta.get("pretty_name"), str):
        problems.append("pretty_name must be a string")
    if not all(isinstance(t, str) for t in meta.get("tags") or []):
        problems.append("tags must be strings")
    return problems


def _check_dataset_info(meta: dict[str, Any]) -> list[str]:
    info = meta.get("dataset_info")
    if info is None:
        return []
    if not isinstance(info, dict) or not isinstance(info.get("splits"), list):
        return ["dataset_info.splits must be a list"]
    problems = []
    total = 0
    for s in info["splits"]:
        if not isinstance(s, dict) or not re.fullmatch(r"\w+(\.\w+)*", str(s.get("name"))):
            problems.append(
                f"dataset_info.splits: bad split {s!r} (name must match \\w+(\\.\\w+)*)"
            )
            continue
        for key in ("num_bytes", "num_examples"):
            if not isinstance(s.get(key), int) or s[key] < 0:
                problems.append(f"dataset_info.splits[{s['name']}].{key} must be a count >= 0")
        total += s.get("num_examples", 0) if isinstance(s.get("num_examples"), int) else 0
    sizes = meta.get("size_categories") or []
    if info["splits"] and sizes and sizes[0] != "other" and sizes[0] != size_category(total):
        problems.append(
            f"size_categories {sizes} does not fit {total} examples ({size_category(total)})"
        )
    return problems
