"""A fake built tree written to the letter of docs/output_tree.md, for tests and benchmarks.

`build_fake_tree` writes a SemanticKITTI-like source tree (scans, labels, copied calib, poses
and times) and a variant tree of random bytes with its manifest.jsonl, run.json,
pipeline.yaml, provenance.zarr, dataset card and SHA256SUMS. The helpers read and rewrite the
metadata, so that a test can break one thing and re-sum the tree.

Used by tests/unit/test_verify.py, tests/unit/test_card.py and benchmarks/verify_speed.py
(`from tests.fake_trees import build_fake_tree`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from urllib.parse import quote

import numpy as np
import yaml

LOST, PARTICLE, ATTENUATED = 5, 3, 7
COPIED = ("sequences/00/calib.txt", "sequences/00/poses.txt", "sequences/00/times.txt")


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_sums(out: Path) -> None:
    """SHA256SUMS over every file except itself and run_report.json, sorted bytewise."""
    rels = []
    for folder, _, names in os.walk(out):
        for name in names:
            rel = Path(folder, name).relative_to(out).as_posix()
            if rel not in ("SHA256SUMS", "run_report.json"):
                rels.append(rel)
    rels.sort(key=str.encode)
    (out / "SHA256SUMS").write_text("".join(f"{sha256(out / r)}  {r}\n" for r in rels))


def write_manifest(out: Path, rows: list[dict]) -> None:
    text = "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows)
    (out / "manifest.jsonl").write_text(text)


def read_manifest(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def read_run(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())


def write_run(out: Path, run: dict) -> None:
    (out / "run.json").write_text(json.dumps(run, sort_keys=True, indent=1) + "\n")


def _write(path: Path, data: bytes) -> dict:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return {"path": None, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def _write_provenance(out: Path, rows: list[dict], mode: str, config_hash: str) -> None:
    import zarr

    root = zarr.open_group(out / "provenance.zarr", mode="w")
    root.attrs.update({"schema_version": 1, "points_mode": mode, "config_hash": config_hash})
    for row in rows:
        rel = row["item_id"].partition(":")[2]
        pts = row["points"]
        group = root.create_group(quote(rel, safe=""))
        group.attrs.update(
            {
                "item_id": row["item_id"],
                "relpath": rel,
                "n_source": pts["source"],
                "n_output": pts["output"],
            }
        )
        n = pts["output"]
        index = group.create_array("source_index", shape=(n,), chunks=(n,), dtype="int64")
        index[:] = np.arange(n, dtype=np.int64)
        outcome = group.create_array("outcome", shape=(n,), chunks=(n,), dtype="uint8")
        outcome[:] = np.zeros(n, dtype=np.uint8)


def build_fake_tree(
    root: Path,
    *,
    n_items: int = 3,
    mode: str = "physical",
    seed: int = 0,
    sequence: str = "00",
    scan_bytes: int = 16,
    card: bool = True,
    points_base: int = 100,
) -> tuple[Path, Path]:
    """A source tree and its (fake) variant tree; returns (source_root, out_root)."""
    rng = np.random.default_rng(seed)
    src, out = root / "src", root / "out"
    seq = f"sequences/{sequence}"
    rows = []
    for i in range(n_items):
        scan_rel, label_rel = f"{seq}/velodyne/{i:06d}.bin", f"{seq}/labels/{i:06d}.label"
        n_src = points_base + 10 * i
        n_out = n_src if mode == "aligned" else n_src - LOST
        src_scan = _write(src / scan_rel, rng.bytes(n_src * scan_bytes)) | {"path": scan_rel}
        src_label = _write(src / label_rel, rng.bytes(n_src * 4)) | {"path": label_rel}
        out_scan = _write(out / scan_rel, rng.bytes(n_out * scan_bytes))
        if mode == "aligned":
            label_bytes = (src / label_rel).read_bytes()
        else:
            label_bytes = rng.bytes(n_out * 4)
        out_label = _write(out / label_rel, label_bytes)
        kept = n_out - PARTICLE - ATTENUATED - (LOST if mode == "aligned" else 0)
        rows.append(
            {
                "item_id": f"semantickitti:{scan_rel}",
                "status": "ok",
                "source": [src_scan, src_label],
                "outputs": [
                    out_scan
                    | {
                        "path": scan_rel,
                        "role": "scan",
                        "records": n_out,
                        "record_bytes": scan_bytes,
                    },
                    out_label
                    | {"path": label_rel, "role": "label", "records": n_out, "record_bytes": 4},
                ],
                "points": {
                    "source": n_src,
                    "output": n_out,
                    "kept": kept,
                    "attenuated": ATTENUATED,
                    "particle": PARTICLE,
                    "lost": LOST,
                },
                "stages": [
                    {
                        "name": "snow",
                        "version": "1",
                        "params_hash": "ab" * 8,
                        "seed_entropy": [seed, 1, 2, 3, 4],
                    }
                ],
            }
        )
    copied = []
    for rel in (f"{seq}/calib.txt", f"{seq}/poses.txt", f"{seq}/times.txt"):
        entry = _write(src / rel, f"{rel} {rng.integers(1 << 30)}\n".encode()) | {"path": rel}
        shutil.copyfile(src / rel, out / rel)
        copied.append(entry)
    pipeline = {
        "schema_version": 1,
        "variant": "snow-10",
        "description": "test",
        "stages": [{"stage": "snow", "rate_mm_h": 10.0, "mode": "strongest"}],
        "writer": {"points": mode, "particle_label": None},
    }
    (out / "pipeline.yaml").write_text(yaml.safe_dump(pipeline, sort_keys=True))
    config_hash = "c" * 64
    write_manifest(out, rows)
    write_run(
        out,
        {
            "lads_version": "0.1.0",
            "git_commit": "0" * 40,
            "config_hash": config_hash,
            "source": "semantickitti",
            "source_root": str(src),
            "variant": "snow-10",
            "seed": seed,
            "points_mode": mode,
            "sensor": "hdl64e",
            "device": "cpu",
            "libraries": {"python": "3.11", "numpy": np.__version__},
            "items": len(rows),
            "failed": 0,
            "copied_files": copied,
        },
    )
    _write_provenance(out, rows, mode, config_hash)
    if card:
        from lads.card import write_card

        write_card(out)
    (out / "run_report.json").write_text('{"complete": true}\n')
    write_sums(out)
    return src, out
