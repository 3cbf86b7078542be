"""Expected source inventories (`manifests/<dataset>.yaml`) and completeness checks.

An inventory says how many items each *group* of a dataset holds (SemanticKITTI: scans per
sequence; nuScenes: keyframes per devkit version; Voxelscape: sequences only, counts
unknown) and names *subsets* of groups, e.g. SemanticKITTI "00-10". `lads verify
--inventory semantickitti-00-10` counts a built tree's items per group and reports what is
missing. The YAML schema is described in manifests/README.md.
"""

from __future__ import annotations

import functools
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from lads.errors import ConfigError
from lads.resources import manifests_dir as shipped_manifests

GROUP_BY = ("sequence", "voxelscape_sequence", "nuscenes_version")
APPROXIMATE_TOLERANCE = 0.01  # relative: an "approximate" count accepts +-1 %
_TOP_KEYS = {
    "schema_version",
    "dataset",
    "group_by",
    "counts",
    "sources",
    "groups",
    "subsets",
    "default_subset",
    "allow_unknown_groups",
    "group_range",
}
_GROUP_KEYS = {"items", "labelled", "split", "verified", "approximate", "note"}
_SUBSET_KEYS = {"description", "groups", "total"}
_SEQ = re.compile(r"^\d{2,3}$")


@dataclass(frozen=True, slots=True)
class Group:
    """One group's expectation: `items` None means the count is unknown (presence only)."""

    name: str
    items: int | None
    labelled: bool
    split: str
    verified: bool
    approximate: bool


@dataclass(frozen=True, slots=True)
class Inventory:
    """A validated `manifests/<dataset>.yaml`."""

    dataset: str
    group_by: str
    counts: str
    groups: dict[str, Group]
    subsets: dict[str, tuple[str, ...]]
    default_subset: str
    allow_unknown_groups: bool
    path: Path


def available() -> list[str]:
    """Dataset names with an inventory file."""
    return sorted(p.stem for p in shipped_manifests().glob("*.yaml"))


@functools.lru_cache(maxsize=16)
def load_inventory(name: str, manifests_dir: Path | None = None) -> Inventory:
    """Load and validate `manifests/<name>.yaml`.

    Raises:
        ConfigError: the file is missing, not YAML, or breaks the schema (unknown keys,
            negative counts, a subset naming an unknown group or a wrong `total`).
    """
    path = (manifests_dir or shipped_manifests()) / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(
            f"{path}: no inventory for dataset {name!r}; known: {available()}. Add the file "
            "(schema in manifests/README.md) or pick another --inventory."
        )
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc}); fix the syntax.") from exc
    return _build(raw, path)


def _fail(path: Path, what: str) -> ConfigError:
    return ConfigError(f"{path}: {what}; see manifests/README.md for the schema.")


def _build(raw: Any, path: Path) -> Inventory:
    if not isinstance(raw, dict):
        raise _fail(path, "expected a mapping at the top level")
    unknown = set(raw) - _TOP_KEYS
    if unknown:
        raise _fail(path, f"unknown keys {sorted(unknown)}")
    if raw.get("schema_version") != 1:
        raise _fail(path, f"schema_version must be 1, got {raw.get('schema_version')!r}")
    if raw.get("dataset") != path.stem:
        raise _fail(path, f"dataset must equal the file name {path.stem!r}")
    if raw.get("group_by") not in GROUP_BY:
        raise _fail(path, f"group_by must be one of {GROUP_BY}, got {raw.get('group_by')!r}")
    groups_raw = dict(raw.get("groups") or {})
    rng = raw.get("group_range")
    if rng is not None:
        groups_raw.update(_expand_range(rng, path))
    groups = {str(k): _group(str(k), v, path) for k, v in groups_raw.items()}
    if not groups:
        raise _fail(path, "no groups")
    subsets: dict[str, tuple[str, ...]] = {}
    for sname, spec in (raw.get("subsets") or {}).items():
        subsets[str(sname)] = _subset(str(sname), spec, groups, path)
    default = str(raw.get("default_subset", ""))
    if default not in subsets:
        raise _fail(path, f"default_subset {default!r} is not one of the subsets {list(subsets)}")
    return Inventory(
        dataset=raw["dataset"],
        group_by=raw["group_by"],
        counts=str(raw.get("counts", "items")),
        groups=groups,
        subsets=subsets,
        default_subset=default,
        allow_unknown_groups=bool(raw.get("allow_unknown_groups", False)),
        path=path,
    )


def _expand_range(rng: Any, path: Path) -> dict[str, dict[str, Any]]:
    if not isinstance(rng, dict) or not {"first", "last", "width"} <= set(rng):
        raise _fail(path, "group_range needs first, last and width")
    extra = {k: v for k, v in rng.items() if k not in {"first", "last", "width"}}
    first, last, width = int(rng["first"]), int(rng["last"]), int(rng["width"])
    return {f"{i:0{width}d}": {"items": None, **extra} for i in range(first, last + 1)}


def _group(name: str, spec: Any, path: Path) -> Group:
    if not isinstance(spec, dict) or set(spec) - _GROUP_KEYS:
        raise _fail(path, f"groups[{name!r}] must be a mapping with keys among {_GROUP_KEYS}")
    items = spec.get("items")
    if items is not None and (not isinstance(items, int) or isinstance(items, bool) or items < 0):
        raise _fail(path, f"groups[{name!r}].items must be a count >= 0 or null, got {items!r}")
    return Group(
        name=name,
        items=items,
        labelled=bool(spec.get("labelled", False)),
        split=str(spec.get("split", "")),
        verified=bool(spec.get("verified", True)),
        approximate=bool(spec.get("approximate", False)),
    )


def _subset(name: str, spec: Any, groups: dict[str, Group], path: Path) -> tuple[str, ...]:
    if not isinstance(spec, dict) or set(spec) - _SUBSET_KEYS or "groups" not in spec:
        raise _fail(path, f"subsets[{name!r}] must map groups (and description, total)")
    members = tuple(groups) if spec["groups"] == "*" else tuple(str(g) for g in spec["groups"])
    missing = [g for g in members if g not in groups]
    if missing:
        raise _fail(path, f"subsets[{name!r}] names unknown groups {missing}")
    total = spec.get("total")
    if total is not None:
        counts = [groups[g].items for g in members]
        if any(c is None for c in counts) or sum(c for c in counts if c) != total:
            raise _fail(path, f"subsets[{name!r}].total is {total} but its groups sum to {counts}")
    return members


def parse_release(release: str) -> tuple[str, str]:
    """Split an inventory name into (dataset, subset): "semantickitti-00-10" ->
    ("semantickitti", "00-10"); "nuscenes-v1.0-mini" -> ("nuscenes", "v1.0-mini"); a bare
    dataset name gives its default subset.

    Raises:
        ConfigError: unknown dataset or subset.
    """
    name, _, subset = release.partition("-")
    inv = load_inventory(name)
    subset = subset or inv.default_subset
    if subset not in inv.subsets:
        raise ConfigError(
            f"{inv.path}: no subset {subset!r} for inventory {release!r}; known: "
            f"{sorted(inv.subsets)}. Use e.g. {name}-{inv.default_subset}."
        )
    return name, subset


def expected_counts(name: str, subset: str | None = None) -> dict[str, int | None]:
    """Expected items per group of one subset (None: count unknown, presence only)."""
    inv = load_inventory(name)
    members = inv.subsets[subset or inv.default_subset]
    return {g: inv.groups[g].items for g in members}


def group_of(item_id: str, group_by: str, *, version: str | None = None) -> str | None:
    """The group of one item id `"<dataset>:<relpath>"`, or None when it is not counted.

    sequence: `sequences/SS/...` -> "SS"; voxelscape_sequence: `SS/...` or
    `sequences/SS/...` -> "SS"; nuscenes_version: keyframes `samples/...` -> `version`,
    sweeps -> None.
    """
    relpath = item_id.partition(":")[2] or item_id
    parts = relpath.split("/")
    if group_by == "nuscenes_version":
        return version if parts[0] == "samples" else None
    if parts[0] == "sequences" and len(parts) > 2:
        return parts[1]
    if group_by == "voxelscape_sequence" and len(parts) > 1 and _SEQ.match(parts[0]):
        return parts[0]
    return None


def notes(name: str, subset: str | None = None) -> list[str]:
    """Caveats of the expected counts of one subset (unverified, approximate, unknown)."""
    inv = load_inventory(name)
    members = [inv.groups[g] for g in inv.subsets[subset or inv.default_subset]]
    out = []
    for label, picked in (
        ("unverified", [g.name for g in members if not g.verified]),
        (
            f"approximate (+-{APPROXIMATE_TOLERANCE:.0%})",
            [g.name for g in members if g.approximate],
        ),
        ("unknown (presence checked only)", [g.name for g in members if g.items is None]),
    ):
        if picked:
            shown = ", ".join(picked[:8]) + (", ..." if len(picked) > 8 else "")
            out.append(
                f"inventory {name}: expected counts {label} for {len(picked)} groups: {shown}"
            )
    return out


def compare(
    item_ids: Iterable[str], name: str, subset: str | None = None, *, version: str | None = None
) -> list[tuple[str, str, str]]:
    """Compare item ids with the expected inventory; returns (path, kind, message) problems.

    Kinds: "incomplete_release" (a group is missing or short of items), "inventory_extra"
    (more items than expected, or items of groups outside the subset). Path is the group's
    folder (e.g. "sequences/00") or the nuScenes version.
    """
    inv = load_inventory(name)
    subset = subset or inv.default_subset
    if subset not in inv.subsets:
        raise ConfigError(f"{inv.path}: no subset {subset!r}; known: {sorted(inv.subsets)}.")
    if inv.group_by == "nuscenes_version" and version is None:
        return [
            (
                ".",
                "incomplete_release",
                f"inventory {name}-{subset}: cannot tell the nuScenes version of this tree (no "
                "'version' in run.json, no v1.0-*/ tables among copied_files, no "
                "lidarseg/<version>/ outputs); the tree lacks the devkit tables it needs.",
            )
        ]
    members = inv.subsets[subset]
    counts = Counter(group_of(i, inv.group_by, version=version) for i in item_ids)
    uncounted = counts.pop(None, 0)
    where = f"inventory {name}-{subset} ({inv.path.name})"
    return [
        *_missing_groups(inv, members, counts, where),
        *_miscounted_groups(inv, members, counts, where),
        *_outside_groups(inv, members, counts, uncounted, where),
    ]


def _missing_groups(
    inv: Inventory, members: Sequence[str], counts: Counter[str | None], where: str
) -> list[tuple[str, str, str]]:
    """One problem naming the groups of the subset that have no items (none if all do)."""
    problems: list[tuple[str, str, str]] = []
    missing = [g for g in members if counts.get(g, 0) == 0]
    if missing:
        expected = sum(inv.groups[g].items or 0 for g in missing)
        problems.append(
            (
                _group_path(inv, missing[0]) if len(missing) == 1 else ".",
                "incomplete_release",
                f"{where}: {len(missing)} group(s) have no items: {', '.join(missing)}"
                + (f" ({expected} {inv.counts} expected)" if expected else "")
                + "; build them (or verify against a smaller subset).",
            )
        )
    return problems


def _miscounted_groups(
    inv: Inventory, members: Sequence[str], counts: Counter[str | None], where: str
) -> list[tuple[str, str, str]]:
    """A problem per group of the subset with some items, but more or fewer than expected."""
    problems: list[tuple[str, str, str]] = []
    for g in members:
        have, grp = counts.get(g, 0), inv.groups[g]
        if have == 0 or grp.items is None or _close(have, grp.items, grp.approximate):
            continue
        kind = "incomplete_release" if have < grp.items else "inventory_extra"
        caveat = "" if grp.verified else " (expected count unverified)"
        problems.append(
            (
                _group_path(inv, g),
                kind,
                f"{where}: group {g} has {have} {inv.counts}, expected {grp.items}{caveat}; "
                + ("build the missing items." if have < grp.items else "explain the extra items."),
            )
        )
    return problems


def _outside_groups(
    inv: Inventory,
    members: Sequence[str],
    counts: Counter[str | None],
    uncounted: int,
    where: str,
) -> list[tuple[str, str, str]]:
    """Problems for items of groups outside the subset and for items of no group."""
    problems: list[tuple[str, str, str]] = []
    strangers = sorted(str(g) for g in counts if g not in members)
    if strangers and not (inv.allow_unknown_groups and all(g not in inv.groups for g in strangers)):
        problems.append(
            (
                ".",
                "inventory_extra",
                f"{where}: items of groups outside the subset: {', '.join(strangers)}; verify with "
                "a subset that includes them or rebuild from the intended source subset.",
            )
        )
    if uncounted and inv.group_by != "nuscenes_version":
        problems.append(
            (
                ".",
                "inventory_extra",
                f"{where}: {uncounted} item(s) do not belong to any {inv.group_by}; their "
                "relative paths do not follow the dataset layout.",
            )
        )
    return problems


def _close(have: int, expected: int, approximate: bool) -> bool:
    if approximate:
        return abs(have - expected) <= APPROXIMATE_TOLERANCE * expected
    return have == expected


def _group_path(inv: Inventory, group: str) -> str:
    if inv.group_by == "sequence":
        return f"sequences/{group}"
    return group


def tree_version(run: dict[str, Any], output_paths: Iterable[str] = ()) -> str | None:
    """The nuScenes version of a built tree: run.json "version", else the `v1.0-*/` folder
    of its copied tables, else the `lidarseg/<version>/` folder of its label outputs."""
    if isinstance(run.get("version"), str):
        return str(run["version"])
    for entry in run.get("copied_files") or ():
        head = str(entry.get("path", "")).split("/")[0] if isinstance(entry, dict) else ""
        if head.startswith("v1.0-"):
            return head
    for path in output_paths:
        parts = path.split("/")
        if len(parts) > 2 and parts[0] == "lidarseg":
            return parts[1]
    return None
