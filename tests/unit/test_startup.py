"""Start-up cost of a build: what a physics-only build imports, and the per-user cache."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from lads import user_cache

CHECK_IMPORTS = """
import sys
from lads.cli import main
from lads.config import find_pipeline, load_pipeline
from lads.runner import run_build
from lads.worker import stages_for
stages_for(load_pipeline(find_pipeline("semantickitti", "rain")))
snow = load_pipeline(find_pipeline("semantickitti", "snow"))
stages_for(snow.with_overrides(intensity="physics"))
print(sorted(m for m in ("torch", "scipy.integrate", "matplotlib.pyplot") if m in sys.modules))
"""


def test_a_physics_only_build_never_imports_torch():
    """torch costs 1.5 s of start-up; only a learned stage may pull it in."""
    out = subprocess.run(
        [sys.executable, "-c", CHECK_IMPORTS], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"


def test_the_user_cache_computes_once_and_survives_damage(tmp_path, monkeypatch):
    monkeypatch.setenv(user_cache.CACHE_ENV, str(tmp_path / "cache"))
    calls = []

    def compute():
        calls.append(1)
        return np.arange(5.0)

    first = user_cache.cached_array("table", "inputs v1", compute)
    again = user_cache.cached_array("table", "inputs v1", compute)
    np.testing.assert_array_equal(first, again)
    assert len(calls) == 1
    user_cache.cached_array("table", "inputs v2", compute)  # another key: computed anew
    assert len(calls) == 2
    for path in (tmp_path / "cache").glob("table-*.npy"):
        path.write_bytes(b"not an array")
    np.testing.assert_array_equal(user_cache.cached_array("table", "inputs v1", compute), first)
    assert len(calls) == 3


def test_an_unwritable_cache_only_costs_the_recomputation(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder should be")
    monkeypatch.setenv(user_cache.CACHE_ENV, str(blocker / "cache"))
    value = user_cache.cached_array("table", "k", lambda: np.ones(3))
    np.testing.assert_array_equal(value, np.ones(3))


def test_workers_started_with_malloc_tuning_get_heap_reuse_back():
    """Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_ set (glibc then stops adapting
    and maps every large array afresh); such a worker re-tunes, any other is left alone."""
    code = "from lads.worker import tune_allocator; print(tune_allocator())"
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    plain = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert plain.stdout.strip() == "False"
    nanny_env = {**env, "MALLOC_TRIM_THRESHOLD_": "65536"}
    dask_like = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=nanny_env
    )
    expected = "True" if sys.platform.startswith("linux") else "False"
    assert dask_like.stdout.strip() == expected
