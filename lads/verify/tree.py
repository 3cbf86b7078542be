"""`verify_tree`: the order of the checks on one tree, and the dataset card check."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from lads import lock
from lads.built_tree import SHA256SUMS
from lads.card import CARD_NAME
from lads.errors import BuildError
from lads.verify import hashing, manifest_checks, provenance, source_checks
from lads.verify.report import VerifyReport
from lads.verify.state import Verifier


def verify_tree(
    out_root: Path,
    source_root: Path | None,
    *,
    regenerate: int = 0,
    seed: int = 0,
    inventory: str | None = None,
    progress: bool | None = False,
    source_items: list[str] | None = None,
) -> VerifyReport:
    """Verify a built tree `out_root` (and its correspondence with `source_root`, if given).

    Args:
        out_root: the output tree (docs/output_tree.md).
        source_root: the source tree it was built from, or None to check the tree alone.
        regenerate: re-process this many random ok items (needs source_root) with
            `lads.worker.regenerate_outputs` and compare their hashes with the manifest.
        seed: seed of the random choice of regenerated items.
        inventory: expected release inventory, e.g. "semantickitti-00-10" (manifests/).
        progress: show a tqdm bar while hashing (None: only on a terminal).
        source_items: item ids of the source tree; when None they are listed with
            `lads.readers.get_reader` if available, otherwise the check is skipped (noted).

    Returns:
        VerifyReport listing every problem found.

    Raises:
        ConfigError: unknown inventory name or subset.
        OutputLockedError: `regenerate` asked while another lads process writes the tree.
    """
    start = time.perf_counter()
    v = Verifier(Path(out_root), None if source_root is None else Path(source_root), progress)
    with _regenerate_lock(v, regenerate):
        _run(v, regenerate=regenerate, seed=seed, inventory=inventory, source_items=source_items)
    return VerifyReport(
        out_root=str(out_root),
        problems=sorted(v.problems, key=lambda p: (p.path, p.kind, p.message)),
        files_checked=v.files_checked,
        bytes_hashed=v.bytes_hashed,
        items=len(v.rows),
        source_files_checked=v.source_files_checked,
        regenerated=v.regenerated,
        seconds=time.perf_counter() - start,
        notes=v.notes,
    )


def _run(
    v: Verifier,
    *,
    regenerate: int,
    seed: int,
    inventory: str | None,
    source_items: list[str] | None,
) -> None:
    if not v.out.is_dir():
        v.add(".", "missing_output", f"{v.out} is not a directory")
        return
    if v.src is not None and not v.src.is_dir():
        v.add(".", "source_unreadable", f"source root {v.src} is not a directory")
        v.src = None
    owner = None if v.holds_lock else lock.holder(v.out)
    if owner is not None and not (v.out / SHA256SUMS).is_file():
        # A first build still running has no SHA256SUMS or manifest: every finding would be
        # one, with advice for a finished tree.
        v.add(".", "build_running", f"{lock.describe(owner)} is writing this tree now")
        return
    _note_lock(v, owner)
    v.walk()
    manifest_checks.load_metadata(v)
    if v.src is not None:
        source_checks.resolve_source_root(v)
    hashing.hash_everything(v)
    hashing.check_sums(v)
    manifest_checks.check_run_json(v)
    manifest_checks.check_rows(v)
    source_checks.check_copied(v)
    provenance.check_provenance(v)
    if v.src is not None:
        source_checks.check_sources(v)
        source_checks.check_source_items(v, source_items)
    if regenerate > 0:
        source_checks.check_regenerated(v, regenerate, seed)
    if inventory:
        source_checks.check_inventory(v, inventory)
    _check_card(v)


@contextlib.contextmanager
def _regenerate_lock(v: Verifier, regenerate: int) -> Iterator[None]:
    """Hold the tree's lock while items are rebuilt for comparison, so that no build changes
    the tree under them. A tree on read-only storage needs no lock (nobody can write it)."""
    if regenerate <= 0 or not v.out.is_dir():
        yield
        return
    try:
        held = lock.acquire(v.out, "verify --regenerate")
    except lock.OutputLockedError:
        raise
    except BuildError as exc:
        v.notes.append(f"verified without the output lock: {exc}")
        yield
        return
    v.holds_lock = True
    try:
        yield
    finally:
        lock.release(held)


def _note_lock(v: Verifier, owner: Any) -> None:
    """Say so when a build is writing a finished tree again (a resume or a repair), or left
    its lock file behind."""
    if owner is not None:
        v.notes.append(
            f"{lock.describe(owner)} is writing this tree now: what follows describes a "
            "moment of that run"
        )
    elif not v.holds_lock and (v.out / lock.LOCK_NAME).exists():
        v.notes.append(
            f"{lock.LOCK_NAME} was left by an interrupted run; the next build removes it"
        )


def _check_card(v: Verifier) -> None:
    if CARD_NAME not in v.files:
        v.notes.append(f"no dataset card ({CARD_NAME}); `lads card` writes one")
        return
    from lads.card import validate_card

    for msg in validate_card((v.out / CARD_NAME).read_text(errors="replace")):
        v.add(CARD_NAME, "card_invalid", msg)
