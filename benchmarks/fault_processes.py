"""Faults that need whole processes or file systems: kills at random moments, builds that
race for one output, a disk that fills up, an output on read-only storage.

Kill and race trials run `lads build` as a user would (`python -m lads.cli`); disk faults use
a small tmpfs when this machine lets us mount one (root on Linux), and otherwise simulate
the failing write (an OSError ENOSPC / EROFS from the writer) in-process, and say which.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from benchmarks.fault_cases import Bench, Result, _complete, build_args, call_lads
from lads.runner import BuildReport

PHASES = ("starting", "items", "finalise", "finished")


def phase_of(out: Path) -> str:
    """Where a killed build stood: before any journal, among items, in finalise, done."""
    if (out / "SHA256SUMS").is_file() and not (out / ".lads-state").exists():
        return "finished"
    if (out / "manifest.jsonl").is_file():
        return "finalise"
    return "items" if (out / ".lads-state").exists() else "starting"


def timed_reference(bench: Bench) -> float:
    """Seconds of one uninterrupted CLI build (process start included)."""
    out = bench.scratch("timed")
    start = time.perf_counter()
    proc = call_lads(build_args(bench, out), bench.work)
    proc.communicate(timeout=900)
    return time.perf_counter() - start


def _wait_for(out: Path, trigger: float | str, proc: subprocess.Popen[bytes]) -> None:
    """Return when the kill moment has come: `trigger` seconds after the start, or (str)
    "item:K" when K items are done, or a step of finalise: "finalise" (the manifest is
    written), "finalise:card" (the dataset card is), "finalise:journal" (the resume journal
    is removed, SHA256SUMS not yet written)."""
    if isinstance(trigger, float | int):
        time.sleep(float(trigger))
        return
    journal = out / ".lads-state" / "items"
    marks = {
        "finalise": lambda: (out / "manifest.jsonl").exists(),
        "finalise:card": lambda: (out / "README.md").exists(),
        "finalise:journal": lambda: (
            (out / "manifest.jsonl").exists() and not (out / ".lads-state").exists()
        ),
    }
    while proc.poll() is None:
        if trigger in marks and marks[trigger]():
            return
        if trigger.startswith("item:") and journal.is_dir():
            if sum(1 for _ in journal.iterdir()) >= int(trigger[5:]):
                return
        time.sleep(0.001)


def kill(
    bench: Bench,
    trigger: float | str,
    sig: int = signal.SIGKILL,
    twice: bool = False,
    delay_s: float = 0.0,
) -> Result:
    """Kill a build at `trigger` (seconds after start, "finalise" or "item:K"; plus
    `delay_s`), twice if asked (again during the resume), then run it to the end; the tree
    must equal the uninterrupted one."""
    label = f"{trigger:.2f}" if isinstance(trigger, float | int) else f"{trigger}+{delay_s:.3f}"
    out = bench.scratch(f"kill-{label}")
    phases = []
    for _ in range(2 if twice else 1):
        proc = call_lads(build_args(bench, out), bench.work, start_new_session=True)
        _wait_for(out, trigger, proc)
        time.sleep(delay_s)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        proc.communicate(timeout=900)
        phases.append(phase_of(out))
    final = call_lads(build_args(bench, out), bench.work)
    stdout, stderr = final.communicate(timeout=900)
    ok, why = bench.identical(out)
    name = f"{signal.Signals(sig).name.lower()}{'_twice' if twice else ''}@{'+'.join(phases)}"
    done = final.returncode == 0 and b"complete" in stdout
    return Result(name, "kill", True, done and ok, f"killed at {label}; {why}")


def race(bench: Bench, wait: bool) -> Result:
    """Two identical builds started at once: one writes, the other refuses naming it (or,
    with --wait, queues behind it); the tree equals the reference either way."""
    out = bench.scratch(f"race-{'wait' if wait else 'nowait'}")
    extra = ("--wait",) if wait else ()
    procs = [call_lads(build_args(bench, out, *extra), bench.work) for _ in range(2)]
    outs = [p.communicate(timeout=900) for p in procs]
    codes = sorted(p.returncode for p in procs)
    refused = [e for (o, e), p in zip(outs, procs, strict=True) if p.returncode == 2]
    named = all(b"is writing this tree" in e and b"pid" in e for e in refused)
    ok, why = bench.identical(out)
    if wait:
        good = codes == [0, 0]
    else:
        good = codes in ([0, 2], [0, 0]) and named
    detail = f"exit codes {codes}; {why}; {refused[0].decode()[:200] if refused else ''}"
    return Result(f"race_{'wait' if wait else 'refuse'}", "concurrent", good, good and ok, detail)


@contextlib.contextmanager
def tmpfs(path: Path, size_bytes: int, readonly: bool = False) -> Iterator[bool]:
    """Mount a tmpfs of `size_bytes` at `path`; yields False when mounting is not allowed."""
    path.mkdir(parents=True, exist_ok=True)
    opts = f"size={max(size_bytes, 65536)}" + (",ro" if readonly else "")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True
    )
    try:
        yield done.returncode == 0
    finally:
        if done.returncode == 0:
            subprocess.run(["umount", "-l", str(path)], capture_output=True)


def _tree_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def disk_full(bench: Bench) -> Result:
    """The output's disk fills up mid-build: a named error, no temp file, run_report.json
    where it fits; after space is freed the same command finishes the identical tree."""
    mount = bench.scratch("full")
    size = int(_tree_bytes(bench.reference) * 0.6)
    with tmpfs(mount, size) as real:
        if not real:
            return _disk_full_simulated(bench)
        out = mount / "out"
        first = bench.build(bench.source, out)
        temps = list(out.rglob("*.lads-tmp")) if out.exists() else []
        caught = not isinstance(first, BuildReport) and "no space left" in str(first)
        subprocess.run(["mount", "-o", f"remount,size={size * 4}", str(mount)], check=True)
        second = bench.build(bench.source, out)
        ok, why = bench.identical(out)
        detail = f"tmpfs {size} B: {str(first)[:160]}; temps left {len(temps)}; {why}"
        survived = caught and not temps and _complete(second) and ok
        return Result("disk_full_tmpfs", "error", caught, survived, detail)


def _disk_full_simulated(bench: Bench) -> Result:
    import lads.files as files

    out = bench.scratch("full-simulated")
    real_replace, calls = os.replace, [0]

    def failing_replace(src: str, dst: str) -> None:
        calls[0] += 1
        if calls[0] > 12:
            raise OSError(errno.ENOSPC, "No space left on device")
        real_replace(src, dst)

    files.os.replace = failing_replace  # type: ignore[attr-defined]
    try:
        first = bench.build(bench.source, out)
    finally:
        files.os.replace = real_replace  # type: ignore[attr-defined]
    temps = list(out.rglob("*.lads-tmp"))
    caught = not isinstance(first, BuildReport) and "no space left" in str(first)
    second = bench.build(bench.source, out)
    ok, why = bench.identical(out)
    survived = caught and not temps and _complete(second) and ok
    return Result("disk_full_simulated", "error", caught, survived, f"{first}; {why}"[:400])


def read_only(bench: Bench) -> Result:
    """An output on read-only storage: refused in words, nothing written."""
    mount = bench.scratch("readonly")
    with tmpfs(mount, 1 << 20, readonly=True) as real:
        if not real:
            return Result("read_only_output", "error", False, False, "cannot mount here: skipped")
        first = bench.build(bench.source, mount / "out")
        caught = not isinstance(first, BuildReport) and "read-only" in str(first)
        nothing = not any(mount.iterdir())
        return Result("read_only_output", "error", caught, caught and nothing, str(first)[:300])


def kill_moments(
    total_s: float, items: int, trials: int, rng: np.random.Generator
) -> list[tuple[float | str, float]]:
    """(trigger, delay) pairs: a third at random times over the whole build (process start
    and imports included), a third right after a random item finished, and a third at the
    steps of finalise (0-20 ms after each), where a timed kill rarely lands: it takes a
    fraction of a second."""
    third = max(trials // 3, 1)
    moments: list[tuple[float | str, float]] = [
        (float(t), 0.0) for t in rng.uniform(0.05 * total_s, 0.9 * total_s, third)
    ]
    moments += [(f"item:{int(k)}", 0.0) for k in rng.integers(1, max(items, 2), third)]
    steps = ("finalise", "finalise:card", "finalise:journal")
    moments += [(steps[i % 3], float(rng.uniform(0.0, 0.02))) for i in range(trials - 2 * third)]
    return moments
