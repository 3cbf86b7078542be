"""The provenance store: `OUT/provenance.zarr`, source_index and outcome per output point.

One subgroup per item (named by the url-quoted scan relpath), so parallel workers write
disjoint nodes and any output point can be traced to its source point.
"""

from __future__ import annotations

import functools
import json
import shutil
import urllib.parse
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from lads.errors import ManifestError
from lads.files import atomic_write

STORE_NAME = "provenance.zarr"
SCHEMA_VERSION = 1
BLOSC_CNAME = "zstd"
BLOSC_LEVEL = 3


def node_name(relpath: str) -> str:
    """Zarr node name of an item: its relpath with every '/' (and '%') quoted."""
    return urllib.parse.quote(relpath, safe="")


def create_store(out_root: Path, *, points_mode: str, config_hash: str) -> None:
    """Create (or reopen, if it matches) the store at the root of the output tree: its root
    group's zarr.json, written directly like the items' groups (`write_item`)."""
    path = out_root / STORE_NAME / "zarr.json"
    attrs = {
        "schema_version": SCHEMA_VERSION,
        "points_mode": points_mode,
        "config_hash": config_hash,
    }
    try:
        if json.loads(path.read_text()).get("attributes") == attrs:
            return
    except (OSError, ValueError, AttributeError):
        pass  # missing or damaged: written anew
    atomic_write(path, _json({"attributes": attrs, "zarr_format": 3, "node_type": "group"}))


def write_item(
    out_root: Path,
    relpath: str,
    item_id: str,
    source_index: npt.NDArray[np.int64],
    outcome: npt.NDArray[np.uint8],
    n_source: int,
    window: tuple[str, ...] = (),
    source_scan: npt.NDArray[np.int16] | None = None,
) -> None:
    """Write one item's provenance (overwriting a partial earlier attempt).

    A sensor transfer's item also gets `window` (attribute: the relpaths of the scans its
    points came from) and `source_scan` ((M,) int16, the index into `window` of each
    point's scan): its source_index is then a row of that scan.

    The group is a plain Zarr v3 group (read back with zarr, `read_item`), but written here
    directly as its five files: zarr's own writer spent ~12 ms of event-loop round trips per
    item whatever the data size, up to half of a physics-only frame's cost. Chunks are one
    per array, Blosc zstd with bit-shuffle (the sorted source indices shrink ~15x against
    zstd alone).
    """
    group = out_root / STORE_NAME / node_name(relpath)
    if group.exists():
        shutil.rmtree(group)
    attrs: dict[str, Any] = {
        "item_id": item_id,
        "relpath": relpath,
        "n_source": int(n_source),
        "n_output": int(source_index.size),
    }
    arrays = [("source_index", source_index.astype("<i8")), ("outcome", outcome)]
    if window:
        attrs["window"] = list(window)
        scans = np.zeros(0, "<i2") if source_scan is None else source_scan.astype("<i2")
        arrays.append(("source_scan", scans))
    for name, values in arrays:
        folder = group / name
        atomic_write(folder / "zarr.json", _json(_array_metadata(values)))
        if values.size:
            atomic_write(folder / "c" / "0", _blosc().encode(values))
    atomic_write(
        group / "zarr.json", _json({"attributes": attrs, "zarr_format": 3, "node_type": "group"})
    )


def _json(value: dict[str, Any]) -> bytes:
    return json.dumps(value, indent=2).encode()


@functools.lru_cache(maxsize=1)
def _blosc() -> Any:
    """numcodecs' Blosc (zarr's own codec); its typesize is the encoded array's itemsize.

    Single-threaded, as zarr sets it: multi-threaded Blosc (numcodecs' default in a main
    thread) compresses to other bytes than single-threaded Blosc (a Dask worker's thread),
    and a tree's bytes must not depend on the backend."""
    from numcodecs import Blosc, blosc

    blosc.use_threads = False

    return Blosc(cname=BLOSC_CNAME, clevel=BLOSC_LEVEL, shuffle=Blosc.BITSHUFFLE, blocksize=0)


def _array_metadata(values: npt.NDArray[Any]) -> dict[str, Any]:
    """Zarr v3 metadata of a 1-D array stored as one chunk (at least 1 long)."""
    itemsize = values.dtype.itemsize
    bytes_codec: dict[str, Any] = {"name": "bytes"}
    if itemsize > 1:
        bytes_codec["configuration"] = {"endian": "little"}
    blosc = {
        "name": "blosc",
        "configuration": {
            "typesize": itemsize,
            "cname": BLOSC_CNAME,
            "clevel": BLOSC_LEVEL,
            "shuffle": "bitshuffle",
            "blocksize": 0,
        },
    }
    return {
        "shape": [int(values.size)],
        "data_type": values.dtype.name,
        "chunk_grid": {
            "name": "regular",
            "configuration": {"chunk_shape": [max(int(values.size), 1)]},
        },
        "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
        "fill_value": 0,
        "codecs": [bytes_codec, blosc],
        "attributes": {},
        "zarr_format": 3,
        "node_type": "array",
        "storage_transformers": [],
    }


def read_item(
    out_root: Path, relpath: str
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.uint8], dict]:
    """(source_index (M,) int64, outcome (M,) uint8, attrs) of one item."""
    source, outcome, attrs = _read_arrays(out_root, relpath, ("source_index", "outcome"))
    return source, outcome, attrs


def read_source_scan(out_root: Path, relpath: str) -> tuple[list[str], npt.NDArray[np.int16]]:
    """(window relpaths, (M,) int16 scan of each point) of a sensor transfer's item; for
    any other item ([relpath], zeros): every point is a row of the item's own scan."""
    attrs = _read_arrays(out_root, relpath, ())[-1]
    window = attrs.get("window")
    if not window:
        return [relpath], np.zeros(int(attrs["n_output"]), np.int16)
    scans, _ = _read_arrays(out_root, relpath, ("source_scan",))
    return list(window), scans


def _read_arrays(out_root: Path, relpath: str, names: tuple[str, ...]) -> tuple[Any, ...]:
    """The arrays `names` of one item's group (numpy), then its attributes.

    Raises:
        ManifestError: the group or an array is missing (an incomplete build).
    """
    import zarr  # here, not at module level: a build only writes (`write_item`)

    path = out_root / STORE_NAME / node_name(relpath)
    try:
        group = zarr.open_group(path, mode="r", zarr_format=3)
        # Arrays written by `write_item`, never subgroups; zarr reads them as numpy.
        arrays = tuple(cast(zarr.Array, group[name])[:] for name in names)
        return (*arrays, dict(group.attrs))
    except (FileNotFoundError, KeyError, zarr.errors.NodeNotFoundError) as exc:  # type: ignore[attr-defined]
        raise ManifestError(
            f"{path}: no provenance for {relpath}; the build is incomplete. Run the same "
            "`lads build` again to finish it."
        ) from exc


def group_files(out_root: Path, relpath: str) -> list[Path]:
    """Every file of one item's group (its metadata and chunks)."""
    base = out_root / STORE_NAME / node_name(relpath)
    return sorted(p for p in base.rglob("*") if p.is_file()) if base.is_dir() else []


def item_intact(out_root: Path, row: dict, listed: dict[str, str] | None = None) -> bool:
    """Whether an ok manifest row's provenance group is whole and agrees with the row.

    The group must open, carry the row's item id, relpath and point counts, and hold
    `source_index` and `outcome` arrays of the row's output length whose outcome counts are
    the row's; when `listed` (SHA256SUMS of a finished earlier run: relpath -> sha256) names
    the group's files, their bytes must still be those.
    """
    from lads.correspondence import outcome_counts
    from lads.files import sha256_file

    relpath = row["item_id"].partition(":")[2]
    points = row.get("points") or {}
    try:
        source_index, outcome, attrs = read_item(out_root, relpath)
    except Exception:  # noqa: BLE001 - damaged metadata or chunks fail in many ways; any of them means rebuild
        return False
    want = {
        "item_id": row["item_id"],
        "relpath": relpath,
        "n_source": points.get("source"),
        "n_output": points.get("output"),
    }
    if {k: attrs.get(k) for k in want} != want or source_index.shape != outcome.shape:
        return False
    if attrs.get("window"):
        try:
            window, scans = read_source_scan(out_root, relpath)
        except Exception:  # noqa: BLE001 - as above: any damage means rebuild
            return False
        if scans.shape != outcome.shape or (scans.size and int(scans.max()) >= len(window)):
            return False
    counts = outcome_counts(points.get("source", -1), outcome, points.get("lost", -1), source_index)
    if counts != points:
        return False
    if listed:
        for path in group_files(out_root, relpath):
            digest = listed.get(path.relative_to(out_root).as_posix())
            if digest is not None and sha256_file(path) != digest:
                return False
    return True
