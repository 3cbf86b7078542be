"""Nothing lost: the fault-injection campaign at test size (benchmarks/faults.py runs it
whole). Every fault must be caught in words and survive the user's remedy with a tree that
verifies and equals the uninterrupted build."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from benchmarks import fault_cases as fc
from benchmarks import fault_processes as fp
from benchmarks.faults import synth_source
from lads import lock


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> fc.Bench:
    work = tmp_path_factory.mktemp("faults")
    return fc.Bench(synth_source(work / "source", frames=4), work, variant="rain")


def _check(result: fc.Result) -> None:
    assert result.caught and result.survived, result.to_json()


@pytest.mark.parametrize("kind", fc.ENTRY_KINDS + fc.POINT_KINDS)
def test_a_bad_source_frame_is_a_named_failure_and_builds_once_restored(bench, kind):
    _check(fc.bad_entry(bench, kind))


@pytest.mark.parametrize("kind", sorted(fc.DAMAGE))
def test_a_rerun_repairs_damage_to_a_finished_tree(bench, kind):
    _check(fc.damage(bench, kind))


def test_a_changed_source_frame_is_rebuilt_on_rerun(bench):
    _check(fc.source_changed(bench))


def test_a_file_lads_did_not_write_is_reported_not_summed(bench):
    _check(fc.foreign_file(bench))


@pytest.mark.parametrize("kind", ["run_json_not_json", "run_json_foreign"])
def test_a_run_json_lads_did_not_write_is_refused_and_nothing_changes(bench, kind):
    _check(fc.run_json(bench, kind))


def test_a_full_disk_stops_the_build_in_words_and_a_rerun_finishes_it(bench):
    _check(fp.disk_full(bench))


def test_read_only_output_is_refused_in_words(bench):
    result = fp.read_only(bench)
    if result.detail.startswith("cannot mount"):
        pytest.skip("no tmpfs can be mounted here (not root)")
    _check(result)


@pytest.fixture(scope="module")
def build_seconds(bench: fc.Bench) -> float:
    return fp.timed_reference(bench)


@pytest.mark.parametrize(
    ("trigger", "delay_s"),
    [
        (0.5, 0.0),
        ("item:2", 0.0),
        ("finalise", 0.0),
        ("finalise:card", 0.0),
        ("finalise:journal", 0.0),
    ],
)
def test_a_killed_build_resumes_to_the_identical_tree(bench, build_seconds, trigger, delay_s):
    at = trigger * build_seconds if isinstance(trigger, float) else trigger
    result = fp.kill(bench, at, delay_s=delay_s)
    _check(result)


def test_sigint_twice_then_resume(bench):
    _check(fp.kill(bench, "item:1", signal.SIGINT, twice=True))


@pytest.mark.parametrize("wait", [False, True])
def test_racing_builds_one_writes_the_other_refuses_or_waits(bench, wait):
    _check(fp.race(bench, wait))


def test_the_lock_names_its_holder_and_goes_with_it(tmp_path: Path):
    held = lock.acquire(tmp_path, "build")
    with pytest.raises(lock.OutputLockedError, match=r"lads build \(pid \d+ on host"):
        lock.acquire(tmp_path, "build")
    assert lock.holder(tmp_path)["purpose"] == "build"
    lock.release(held)
    assert lock.holder(tmp_path) is None and not (tmp_path / lock.LOCK_NAME).exists()
    (tmp_path / lock.LOCK_NAME).write_text('{"pid": 1, "host": "x"}')  # left by a crash
    lock.release(lock.acquire(tmp_path, "build"))  # the kernel's flock is gone with its holder


def test_without_flock_the_lock_files_existence_is_the_lock(tmp_path: Path, monkeypatch):
    import errno
    import os

    def no_flock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(lock.fcntl, "flock", no_flock)
    held = lock.acquire(tmp_path, "build")
    with pytest.raises(lock.OutputLockedError, match="pid"):
        lock.acquire(tmp_path, "build")  # this very process holds it: alive
    lock.release(held)
    dead = {"pid": 2**22 + 12345, "host": lock.socket.gethostname(), "purpose": "build"}
    (tmp_path / lock.LOCK_NAME).write_text(lock.json.dumps(dead))  # a crashed holder
    lock.release(lock.acquire(tmp_path, "build"))
    other = dict(dead, host="another-machine", pid=os.getpid())
    (tmp_path / lock.LOCK_NAME).write_text(lock.json.dumps(other))
    with pytest.raises(lock.OutputLockedError, match="another-machine.*delete"):
        lock.acquire(tmp_path, "build")  # cannot be judged from here: say how to clear it


def test_verify_regenerate_takes_the_lock_and_plain_verify_notes_a_running_build(bench):
    from lads.verify import verify_tree

    held = lock.acquire(bench.reference, "build")
    try:
        with pytest.raises(lock.OutputLockedError, match="is writing this tree"):
            verify_tree(bench.reference, bench.source, regenerate=1)
        report = verify_tree(bench.reference, bench.source)
        assert report.ok and any("is writing this tree now" in n for n in report.notes)
    finally:
        lock.release(held)
    assert verify_tree(bench.reference, bench.source, regenerate=1).ok


def test_a_first_build_still_running_is_reported_as_such(tmp_path):
    """Before its first finish a tree has no SHA256SUMS or manifest: verify and card say a
    build is running instead of advising repairs of a finished tree."""
    from lads.errors import BuildError
    from lads.finalise import refresh_card
    from lads.verify import verify_tree

    tree = tmp_path / "tree"
    tree.mkdir()
    held = lock.acquire(tree, "build")
    try:
        report = verify_tree(tree, None)
        assert [p.kind for p in report.problems] == ["build_running"]
        with pytest.raises(BuildError, match="is writing this tree now"):
            refresh_card(tree)
    finally:
        lock.release(held)
