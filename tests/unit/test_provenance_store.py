"""The provenance store as lads writes it: a Zarr v3 group per item that zarr reads back,
whose bytes do not depend on the thread or process that wrote it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import zarr

from lads import provenance

WRITE_TWICE = """
import sys, threading
from pathlib import Path
import numpy as np
from lads import provenance
out = Path(sys.argv[1])
n = 200_000
source_index = np.concatenate([np.arange(n), -np.ones(500, np.int64)])
outcome = np.zeros(source_index.size, np.uint8)
outcome[-500:] = 2
provenance.write_item(out / "main", "a.bin", "x:a.bin", source_index, outcome, n)
t = threading.Thread(target=provenance.write_item,
                     args=(out / "thread", "a.bin", "x:a.bin", source_index, outcome, n))
t.start(); t.join()
print("zarr" in sys.modules)
"""


def test_an_item_group_reads_back_with_zarr(tmp_path):
    provenance.create_store(tmp_path, points_mode="physical", config_hash="abc")
    source_index = np.array([0, 1, 3, -1], dtype=np.int64)
    outcome = np.array([0, 1, 0, 2], dtype=np.uint8)
    provenance.write_item(tmp_path, "seq/a.bin", "kitti:seq/a.bin", source_index, outcome, 5)
    group = zarr.open_group(tmp_path / provenance.STORE_NAME, mode="r")
    assert dict(group.attrs)["config_hash"] == "abc"
    item = group[provenance.node_name("seq/a.bin")]
    np.testing.assert_array_equal(item["source_index"][:], source_index)
    np.testing.assert_array_equal(item["outcome"][:], outcome)
    assert dict(item.attrs) == {
        "item_id": "kitti:seq/a.bin",
        "relpath": "seq/a.bin",
        "n_source": 5,
        "n_output": 4,
    }
    provenance.write_item(
        tmp_path, "seq/a.bin", "kitti:seq/a.bin", source_index[:0], outcome[:0], 5
    )
    again, _, attrs = provenance.read_item(tmp_path, "seq/a.bin")
    assert again.size == 0 and attrs["n_output"] == 0


def test_the_bytes_do_not_depend_on_the_writing_thread(tmp_path):
    """A build writes from a process's main thread (loky, --jobs 1) or from a worker thread
    (Dask); compressed chunks must be the same bytes either way, before zarr is imported."""
    out = subprocess.run(
        [sys.executable, "-c", WRITE_TWICE, str(tmp_path)],
        check=True,
        capture_output=True,
        text=True,
    )
    assert out.stdout.strip() == "False"  # the writer works without zarr loaded
    main = sorted(p for p in (tmp_path / "main").rglob("*") if p.is_file())
    thread = sorted(p for p in (tmp_path / "thread").rglob("*") if p.is_file())
    assert [p.relative_to(tmp_path / "main") for p in main] == [
        p.relative_to(tmp_path / "thread") for p in thread
    ]
    for a, b in zip(main, thread, strict=True):
        assert a.read_bytes() == b.read_bytes(), a
