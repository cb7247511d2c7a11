"""`ilcforce compare` runs its methods in parallel worker processes: interrupts, faults and results.

What the parallel path must keep from the sequential one: a Ctrl-C (to the parent, as a terminal
sends it) leaves every method's store valid with its finished iterations and exits 130 with one
line; `compare` then resumes each store; a worker that dies is reported in one line, exit 2. That
the stored numbers equal a sequential run's is pinned by tests/test_reference_run.py (the reference
was written by the sequential compare of the code before it ran in parallel).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from ilcforce import store

METHODS = ("c1", "c2", "c3")
SHORT = ("--set", "reference.duration=0.2")
#: Interrupted runs use the paper's full 2 s horizon and many iterations, so they are still running
#: when the test interrupts them (a short horizon finishes 200 iterations before the first poll).
LONG = "200"


def _compare(results, iters: str, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "ilcforce", "compare", "--methods", ",".join(METHODS), "-n", iters,
           "--results", str(results), *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _store(results, method: str):
    """The one store of ``method`` under ``results`` (a run with --set lives in a variant folder)."""
    found = sorted(results.rglob(f"{method}.h5"))
    assert len(found) == 1, found
    return found[0]


def _wait_until_every_store_has(proc, results, n: int, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"compare ended before it could be interrupted: {proc.communicate()[1]}")
        counts = []
        for method in METHODS:
            path = results / "paper" / f"{method}.h5"
            try:
                counts.append(len(store.iterations(path)) if path.exists() else 0)
            except store.StoreError:
                counts.append(0)
        if min(counts) >= n:
            return
        time.sleep(0.01)
    pytest.fail("timed out waiting for iterations")


def _workers(parent_pid: int) -> list[int]:
    """PIDs of the parent's child processes (Linux /proc)."""
    children = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as handle:
                    fields = handle.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == parent_pid:
                children.append(int(entry))
    return children


def test_sigterm_stops_compare_like_ctrl_c_and_says_so(tmp_path):
    results = tmp_path / "results"
    proc = _compare(results, LONG)
    _wait_until_every_store_has(proc, results, 1)
    proc.send_signal(signal.SIGTERM)  # to the parent only: it passes it on to its workers
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 143, stderr
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1].startswith("terminated (SIGTERM): every finished iteration is stored")
    for method in METHODS:
        path = results / "paper" / f"{method}.h5"
        store.validate(path)
        assert store.read_provenance(path)["run_state"] == "partial"


@pytest.mark.slow  # among the slowest of the suite (8-28 s); `make test-slow` runs it
def test_ctrl_c_leaves_every_store_partial_and_valid_then_compare_resumes(tmp_path):
    results = tmp_path / "results"
    proc = _compare(results, LONG)
    _wait_until_every_store_has(proc, results, 1)
    proc.send_signal(signal.SIGINT)  # to the parent only: it passes the interrupt on to its workers
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "run the same command to continue" in stderr  # compare has no --resume
    stored = {}
    for method in METHODS:
        path = results / "paper" / f"{method}.h5"
        store.validate(path)
        assert store.read_provenance(path)["run_state"] == "partial"
        stored[method] = len(store.iterations(path))
        assert 1 <= stored[method] < int(LONG)  # stopped early, after at least the iteration waited for
    again = _compare(results, LONG)
    _wait_until_every_store_has(again, results, max(stored.values()) + 1)  # resumed, not restarted
    again.send_signal(signal.SIGINT)
    again.communicate(timeout=120)
    for method in METHODS:
        path = results / "paper" / f"{method}.h5"
        store.validate(path)
        assert store.iterations(path) == list(range(len(store.iterations(path))))
        assert len(store.iterations(path)) >= stored[method]


def test_a_killed_worker_is_one_line_and_exit_2(tmp_path):
    results = tmp_path / "results"
    proc = _compare(results, LONG)
    _wait_until_every_store_has(proc, results, 1)
    victim = _workers(proc.pid)
    assert len(victim) == len(METHODS), victim  # one worker process per method
    os.kill(victim[0], signal.SIGKILL)
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)  # stop the other two
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 2, stderr
    lines = [line for line in stderr.strip().splitlines() if "stopping after" not in line]
    assert len(lines) == 1 and "killed by signal 9" in lines[0], stderr
    for method in METHODS:  # the killed worker's store too: commits are atomic
        store.validate(results / "paper" / f"{method}.h5")


def test_compare_runs_only_what_is_missing(tmp_path):
    results = tmp_path / "results"
    first = _compare(results, "2", *SHORT)
    out, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    assert "paper: The paper's setup" in out  # the title comes from the experiment
    before = {m: _store(results, m).stat().st_mtime_ns for m in METHODS}
    second = _compare(results, "2", *SHORT)
    out2, err2 = second.communicate(timeout=300)
    assert second.returncode == 0, err2
    assert before == {m: _store(results, m).stat().st_mtime_ns for m in METHODS}
    assert out2 == out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.slow  # among the slowest of the suite (8-28 s); `make test-slow` runs it
def test_workers_stop_when_compare_is_killed_and_a_rerun_continues(tmp_path):
    """kill -9 of `compare` left its workers running, orphaned, holding their stores' locks: a rerun
    was refused ("being written by another ilcforce process") until they finished every iteration
    (found by an attack on the CLI). Each now stops after the iteration it is on is stored."""
    results = tmp_path / "results"
    proc = _compare(results, LONG)
    _wait_until_every_store_has(proc, results, 1)
    workers = _workers(proc.pid)
    assert len(workers) == len(METHODS), workers
    proc.kill()
    proc.communicate(timeout=60)
    deadline = time.monotonic() + 60
    while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(pid) for pid in workers), "the workers outlived their killed parent"
    stored = {}
    for method in METHODS:
        path = results / "paper" / f"{method}.h5"
        store.validate(path)
        stored[method] = len(store.iterations(path))
        assert store.read_provenance(path)["run_state"] == "partial" and stored[method] < int(LONG)
    again = _compare(results, LONG)
    _wait_until_every_store_has(again, results, max(stored.values()) + 1)  # not refused: resumed
    again.send_signal(signal.SIGINT)
    _, stderr = again.communicate(timeout=120)
    assert again.returncode == 130 and "being written by another" not in stderr, stderr
