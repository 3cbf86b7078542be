"""The output folder of a build: never inside or around the source, created, claimed for one
build plan (an empty folder, or a partial build of the same plan), and the source's copied
files (calibration, poses, tables) put in it byte for byte."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lads.built_tree import PLAN_JSON, RUN_JSON, STATE_DIR, BuildPlan, identity
from lads.errors import BuildError
from lads.files import atomic_copy, atomic_write, sha256_file
from lads.lock import LOCK_NAME
from lads.readers.base import unreadable_reason


def check_paths(source_root: Path, out_root: Path) -> None:
    """BuildError when OUT is the source tree, inside it or around it."""
    src, out = source_root.resolve(), out_root.resolve()
    if out == src or src in out.parents:
        raise BuildError(
            f"{out_root}: the output directory is inside the source tree {source_root}; lads never "
            "writes into a source dataset. Choose an --out outside it."
        )
    if out in src.parents:
        raise BuildError(
            f"{out_root}: the output directory contains the source tree {source_root}; choose an "
            "--out that is neither inside nor around the source."
        )


def previous_identity(path: Path, ident: dict[str, Any]) -> dict[str, Any]:
    """The build identity recorded in OUT's plan.json or run.json, or a BuildError when the
    file is not a lads record (not JSON, or JSON without the identity keys)."""
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BuildError(
            f"{path}: not a lads build record ({exc}); the output folder holds something lads "
            "did not write, or a damaged build. Choose an empty --out, or delete the folder "
            "to rebuild."
        ) from exc
    if not isinstance(record, dict) or "config_hash" not in record or "source" not in record:
        raise BuildError(
            f"{path}: a JSON file lads did not write (no source and config_hash); the output "
            "folder is not a lads build. Choose an empty or new --out."
        )
    return {k: record.get(k) for k in ident}


def claim_output(out_root: Path, plan: BuildPlan) -> None:
    """Refuse to mix builds: OUT must be empty, or a (partial) build of the same plan."""
    ident = identity(plan)
    marker = out_root / STATE_DIR / PLAN_JSON
    previous: dict[str, Any] | None = None
    if marker.is_file():
        previous = previous_identity(marker, ident)
    elif (out_root / RUN_JSON).exists():
        previous = previous_identity(out_root / RUN_JSON, ident)
    elif any(p.name != LOCK_NAME for p in out_root.iterdir()):
        raise BuildError(
            f"{out_root}: the directory is not empty and holds no lads build; choose an empty or "
            "new --out."
        )
    if previous is not None and previous != ident:
        old_variant = _recorded_variant(marker if marker.is_file() else out_root / RUN_JSON)
        diff = [
            _difference(k, previous.get(k), ident[k], old_variant, plan.pipeline.variant)
            for k in sorted(ident)
            if previous.get(k) != ident[k]
        ]
        raise BuildError(
            f"{out_root}: holds a build with other settings ({'; '.join(diff)}); use "
            "another --out, or delete it to rebuild."
        )
    # The variant rides along (not part of the identity) so a refusal can name it.
    record = {**ident, "variant": plan.pipeline.variant}
    atomic_write(marker, json.dumps(record, sort_keys=True).encode())


def _recorded_variant(path: Path) -> str | None:
    try:
        variant = json.loads(path.read_text()).get("variant")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        return None
    return variant if isinstance(variant, str) else None


def _difference(key: str, old: Any, new: Any, old_variant: str | None, variant: str) -> str:
    """One differing identity key in words: the pipeline by its variant names."""
    if key != "config_hash":
        return f"{key} {old!r} there, {new!r} here"
    if old_variant is not None and old_variant != variant:
        return f"variant {old_variant!r} there, {variant!r} here"
    return f"the pipeline of variant {variant!r} with other parameters (its pipeline.yaml)"


def copy_source_files(reader: Any, source_root: Path, out_root: Path) -> list[dict[str, Any]]:
    """Copy the reader's `copied_files` into OUT (skipping identical ones); their manifest
    rows {path, bytes, sha256}."""
    rows = []
    for rel in sorted(reader.copied_files()):
        src, dst = source_root / rel, out_root / rel
        try:
            digest, size = sha256_file(src), src.stat().st_size
        except OSError as exc:
            raise BuildError(
                f"{src}: a file the build copies byte for byte cannot be read "
                f"({unreadable_reason(src, exc)}); restore it in the source, then run again."
            ) from exc
        if not (dst.is_file() and sha256_file(dst) == digest):
            atomic_copy(src, dst)
        rows.append({"path": rel, "bytes": size, "sha256": digest})
    return rows
