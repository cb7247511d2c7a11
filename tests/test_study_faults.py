"""Studies under faults: a worker killed mid-cell, the driver killed mid-study, a remote scheduler
(started here as `dask scheduler` + `dask worker` subprocesses on 127.0.0.1), an unreachable one.

Every subprocess is bounded in time and torn down in a ``finally``.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
import pandas as pd
import pytest

from ilcforce.study import run_study, tidy_metrics
from ilcforce.study.cell import run_cell

from test_study import TINY_TOML, small_study, write_study_file

# The fault-injecting cell functions below run in Dask worker processes that cannot import this
# test module: ship them by value.
cloudpickle.register_pickle_by_value(sys.modules[__name__])

CLI = [sys.executable, "-m", "ilcforce"]


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)


def killing_cell(marker_dir: str):
    """A cell function whose worker process SIGKILLs itself mid-cell: once for (seed 0, c1), always
    for (seed 1, c3)."""

    def cell(config, method, keep):
        seed = config.experiment.seed
        marker = Path(marker_dir) / f"{seed}-{method}"
        always = (seed, method) == (1, "c3")
        if always or ((seed, method) == (0, "c1") and not marker.exists()):
            marker.write_text("killed")
            os.kill(os.getpid(), signal.SIGKILL)
        return run_cell(config, method, keep)

    return cell


def test_worker_killed_mid_cell_is_retried_then_recorded(tmp_path):
    """On a 2-process LocalCluster: a killed worker's cell is retried once, then recorded as failed;
    every finished cell equals the in-process run bit for bit (the LocalCluster test of the suite)."""
    study = small_study()
    reference = run_study(study, tmp_path / "ref", workers=1)
    (tmp_path / "markers").mkdir()
    summary = run_study(study, tmp_path / "killed", workers=2, cell_function=killing_cell(str(tmp_path / "markers")))
    assert [(c.seed, c.method) for c, _ in summary.failed] == [(1, "c3")]
    assert "worker process died" in summary.failed[0][1]
    from ilcforce.study import read_study

    table = read_study(summary.path).cells.set_index(["seed", "method"])
    assert table.loc[(0, "c1"), "state"] == "done" and table.loc[(0, "c1"), "attempts"] == 2
    assert table.loc[(1, "c3"), "state"] == "failed" and table.loc[(1, "c3"), "attempts"] == 2
    # the cells that finished are the in-process ones bit for bit
    ok = tidy_metrics(summary.path)
    expected = tidy_metrics(reference.path)
    expected = expected[~((expected["seed"] == 1) & (expected["method"] == "c3"))].reset_index(drop=True)
    pd.testing.assert_frame_equal(ok, expected, check_exact=True)
    session = read_study(summary.path).sessions[-1]
    assert session["scheduler"] == "LocalCluster" and session["workers"] == 2
    assert "dask" in session["versions"]


def crowding_cell(marker_dir: str, kill: frozenset):
    """A cell function that returns how many other cells its worker holds (queued, waiting or
    running beside it), looked at as it starts and again 0.2 s later; for a cell in ``kill`` its
    first run SIGKILLs its worker."""

    def cell(i):
        from distributed import get_worker

        worker = get_worker()
        me = worker.get_current_task()

        def others() -> int:
            return sum(1 for key, ts in worker.state.tasks.items()
                       if key != me and ts.state in ("waiting", "ready", "constrained", "executing"))

        seen = others()
        marker = Path(marker_dir) / str(i)
        if i in kill and not marker.exists():
            marker.write_text("killed")
            os.kill(os.getpid(), signal.SIGKILL)
        time.sleep(0.2)
        return {"i": i, "others": max(seen, others())}

    return cell


def test_a_worker_never_holds_a_second_cell_and_kills_spare_the_innocent(tmp_path):
    """The scheduler gives each single-threaded worker one cell at a time, so a cell that kills its
    worker takes no waiting cell with it, and no cell is ever pinned to a worker (a cell pinned to a
    worker that died while none was running stayed unscheduled for good: the suite hung in CI)."""
    import threading
    from collections import namedtuple

    from ilcforce.study.dask_run import dask_client, run_on_dask

    Job = namedtuple("Job", "key")
    kill = frozenset({1, 4, 5, 9})
    outcomes: list = []

    def drive() -> None:
        with dask_client(2, None) as client:
            jobs = [(Job(str(i)), (i,)) for i in range(12)]
            outcomes.extend(run_on_dask(client, jobs, crowding_cell(str(tmp_path), kill), in_flight=4))

    thread = threading.Thread(target=drive, daemon=True)
    thread.start()
    thread.join(timeout=240)
    assert not thread.is_alive(), f"the study hung after {len(outcomes)} of 12 cells"
    by_key = {cell.key: (attempt, result, message) for cell, attempt, result, message in outcomes}
    assert sorted(by_key, key=int) == [str(i) for i in range(12)]
    for i in range(12):
        attempt, result, message = by_key[str(i)]
        assert message is None and result["i"] == i
        assert attempt == (2 if i in kill else 1), f"cell {i}: {attempt} attempts"
        assert result["others"] == 0, f"cell {i} shared its worker with {result['others']} other cells"


def losing_cell(marker_dir: str):
    """Cell "fast" returns at once. Cell "lost" returns after 0.2 s and, the first time, its worker
    process dies 0.3 s later, idle, holding the result; computed again, it takes 3 s."""

    def cell(name):
        import threading

        marker = Path(marker_dir) / name
        if name == "lost" and not marker.exists():
            marker.write_text("lost")
            time.sleep(0.2)
            threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGKILL)).start()
            return {"name": name, "run": 1}
        time.sleep(3.0 if name == "lost" else 0.0)
        return {"name": name, "run": 2 if name == "lost" else 1}

    return cell


def test_a_result_lost_with_its_worker_before_it_was_fetched_is_computed_again(tmp_path):
    """While the driver commits one cell, another finishes and its worker dies before the driver
    fetched its result. Dask computes the cell again; that is still the same attempt, not a failure
    (it was recorded as failed, 'NoneType: None', when the driver took a lost future for a failed one)."""
    from collections import namedtuple

    from ilcforce.study.dask_run import dask_client, run_on_dask

    Job = namedtuple("Job", "key")
    outcomes = []
    with dask_client(2, None) as client:
        for cell, attempt, result, message in run_on_dask(
                client, [(Job("fast"), ("fast",)), (Job("lost"), ("lost",))], losing_cell(str(tmp_path)), in_flight=2):
            outcomes.append((cell.key, attempt, result, message))
            time.sleep(1.5)  # a slow commit: "lost" finishes and loses its worker meanwhile
    assert outcomes == [("fast", 1, {"name": "fast", "run": 1}, None),
                        ("lost", 1, {"name": "lost", "run": 2}, None)]


def freezing_cell(marker_dir: str):
    """Cell 1 freezes its worker process (SIGSTOP: no heartbeat, no progress) the first time."""

    def cell(i):
        marker = Path(marker_dir) / str(i)
        if i == 1 and not marker.exists():
            marker.write_text("froze")
            os.kill(os.getpid(), signal.SIGSTOP)
        time.sleep(0.2)
        return {"i": i}

    return cell


@pytest.mark.slow  # among the slowest of the suite (8-28 s); `make test-slow` runs it
def test_a_frozen_worker_is_restarted_and_its_cell_retried(tmp_path, monkeypatch):
    """A worker that stops answering (kill -STOP, a hung machine) stalled the study for 10 minutes,
    Dask's default heartbeat timeout checked at that period. The local scheduler now has the nanny
    restart it after LOCAL_WORKER_TTL (shortened here; Dask's floor is 10 heartbeats, 5 s): the frozen
    cell counts as a failed attempt and succeeds on its retry, every other cell on its first."""
    import threading
    from collections import namedtuple

    from ilcforce.study import dask_run

    monkeypatch.setattr(dask_run, "LOCAL_WORKER_TTL", 2.0)
    Job = namedtuple("Job", "key")
    outcomes: list = []

    def drive() -> None:
        with dask_run.dask_client(2, None) as client:
            jobs = [(Job(str(i)), (i,)) for i in range(4)]
            outcomes.extend(run for run in dask_run.run_on_dask(client, jobs, freezing_cell(str(tmp_path)), in_flight=4))

    started = time.monotonic()
    thread = threading.Thread(target=drive, daemon=True)
    thread.start()
    thread.join(timeout=120)
    assert not thread.is_alive(), f"the study stalled on the frozen worker ({len(outcomes)} of 4 cells)"
    by_key = {cell.key: (attempt, result, message) for cell, attempt, result, message in outcomes}
    assert by_key == {str(i): (2 if i == 1 else 1, {"i": i}, None) for i in range(4)}, by_key
    assert time.monotonic() - started < 60


def _wait_for_a_committed_cell(driver: subprocess.Popen, journal: Path, log) -> None:
    """Until the study driver has committed a cell (a journal record), so a signal lands mid-study."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and driver.poll() is None:
        if journal.is_dir() and any(p.suffix == ".json" for p in journal.iterdir()):
            break
        time.sleep(0.01)
    assert driver.poll() is None, f"the driver ended before it could be stopped: {log()!r}"


def test_driver_killed_mid_study_rerun_completes_identically(tmp_path):
    study_file = write_study_file(tmp_path, TINY_TOML.replace('seeds = "0-1"', 'seeds = "0-5"'))
    results = tmp_path / "r"
    journal = results / "studies" / "tiny.h5.journal"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    log = tmp_path / "driver.log"
    with open(log, "wb") as stderr:
        driver = subprocess.Popen([*CLI, "study", str(study_file), "--results", str(results), "--workers", "1",
                                   "--quiet"], env=env, stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        _wait_for_a_committed_cell(driver, journal, log.read_text)
        driver.send_signal(signal.SIGKILL)
        driver.wait(timeout=30)
    finally:
        _stop(driver)
    from ilcforce.store.study import read_tables

    _header, _metrics, cells = read_tables(results / "studies" / "tiny.h5")
    stored = len(cells)
    assert 1 <= stored < 24, f"{stored} cells stored at the kill: the kill must land mid-study"
    rerun = subprocess.run([*CLI, "study", str(study_file), "--results", str(results), "--workers", "1"],
                           capture_output=True, text=True, timeout=300, env=env)
    assert rerun.returncode == 0, rerun.stderr
    assert f"({stored} already stored, {24 - stored} run, 0 failed)" in rerun.stdout
    clean = tmp_path / "clean"
    run_study(small_study(seeds="0-5", sweep={"c3.eta": [5.0, 2.0]}), clean, workers=1)
    pd.testing.assert_frame_equal(tidy_metrics(results / "studies" / "tiny.h5"),
                                  tidy_metrics(clean / "studies" / "tiny.h5"), check_exact=True)


@pytest.mark.parametrize("workers", ["1", "2"])
def test_sigterm_mid_study_commits_says_so_and_a_rerun_completes(tmp_path, workers):
    """SIGTERM (a batch system's stop) ended the driver silently (exit 143, a semaphore warning);
    it now takes Ctrl-C's path: one line, exit 143, every finished cell stored, rerun completes."""
    study_file = write_study_file(tmp_path, TINY_TOML.replace('seeds = "0-1"', 'seeds = "0-5"'))
    results = tmp_path / "r"
    journal = results / "studies" / "tiny.h5.journal"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    driver = subprocess.Popen([*CLI, "study", str(study_file), "--results", str(results), "--workers", workers,
                               "--quiet"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_a_committed_cell(driver, journal, lambda: "(stderr is read at the end)")
        driver.send_signal(signal.SIGTERM)
        _, stderr = driver.communicate(timeout=60)
    finally:
        _stop(driver)
    assert driver.returncode == 143, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines == ["terminated (SIGTERM): every finished cell is stored; rerun the same command to continue"], stderr
    rerun = subprocess.run([*CLI, "study", str(study_file), "--results", str(results), "--workers", "1"],
                           capture_output=True, text=True, timeout=300, env=env)
    assert rerun.returncode == 0, rerun.stderr
    assert "24 cells (" in rerun.stdout and ", 0 failed)" in rerun.stdout, rerun.stdout


def test_remote_scheduler_runs_a_study(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ}
    scheduler = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port",
                                  str(port), "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
    worker = None
    try:
        deadline = time.monotonic() + 60
        while True:  # the scheduler takes a few seconds to listen
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline and scheduler.poll() is None, "dask scheduler did not start"
                time.sleep(0.1)
        worker = subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nworkers", "1",
                                   "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard"],
                                  env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        study = small_study()
        summary = run_study(study, tmp_path / "remote", scheduler=address)
        assert summary.failed == () and summary.ran == 4
        reference = run_study(study, tmp_path / "local", workers=1)
        pd.testing.assert_frame_equal(tidy_metrics(summary.path), tidy_metrics(reference.path), check_exact=True)
        from ilcforce.study import read_study

        session = read_study(summary.path).sessions[-1]
        assert session["scheduler"] == address and session["workers"] == 1
    finally:
        if worker is not None:
            _stop(worker)
        _stop(scheduler)


def _foreign_service(silent: bool = False):
    """A TCP service on 127.0.0.1 that is not a Dask scheduler: it answers like an HTTP server, or
    (``silent``) accepts and says nothing, as an HTTP server does until it has a request."""
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    server.settimeout(0.2)
    stop = threading.Event()

    def serve():
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            with conn:
                if silent:  # Dask's client waited for its handshake for ever (found by an attack)
                    stop.wait(30)
                    continue
                conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Length: 5\r\n\r\nhello" * 50)
    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return server, stop, thread


@pytest.mark.parametrize("kind", ["refused", "malformed", "foreign", "silent"])
def test_unreachable_scheduler_is_one_line_in_bounded_time(tmp_path, kind):
    study_file = write_study_file(tmp_path, TINY_TOML)
    service = None
    if kind == "refused":
        address = f"tcp://127.0.0.1:{_free_port()}"
    elif kind == "malformed":
        address = "nonsense-address"
    else:
        service = _foreign_service(silent=kind == "silent")
        address = f"tcp://127.0.0.1:{service[0].getsockname()[1]}"
    try:
        start = time.monotonic()
        result = subprocess.run([*CLI, "study", str(study_file), "--results", str(tmp_path / "r"), "--scheduler",
                                 address, "--timeout", "2"], capture_output=True, text=True, timeout=120)
        elapsed = time.monotonic() - start
    finally:
        if service is not None:
            service[1].set()
            service[2].join(timeout=5)
            service[0].close()
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    assert "scheduler" in result.stderr
    # 2 s to connect plus the interpreter's start-up (imports take a few seconds on a loaded machine)
    assert elapsed < 60, f"took {elapsed:.1f} s"
    # no empty study store (nor its lock, nor the folders made for it) is left for a later --resume or
    # report to pick up
    assert not (tmp_path / "r").exists(), list((tmp_path / "r").rglob("*"))


def test_a_study_that_cannot_start_keeps_an_existing_store(tmp_path, monkeypatch):
    """Only a store the failed run made is removed: one with cells from before stays as it was."""
    import distributed

    from ilcforce.store.study import read_tables
    from ilcforce.study import StudyRunError

    run_study(small_study(seeds="0-1"), tmp_path, workers=1)
    path = tmp_path / "studies" / "tiny.h5"
    before = len(read_tables(path)[2])

    def failing(*args, **kwargs):
        raise RuntimeError("Nanny failed to start.")

    monkeypatch.setattr(distributed, "LocalCluster", failing)
    with pytest.raises(StudyRunError):
        run_study(small_study(seeds="0-3"), tmp_path, workers=2)
    assert len(read_tables(path)[2]) == before


def test_file_size_limit_is_one_line_and_a_rerun_completes(tmp_path):
    """`ulimit -f` (like a full disk) stops the study with one line, exit 2; the cells committed before
    are kept and a rerun without the limit completes with the clean run's metrics."""
    import resource

    study_file = write_study_file(tmp_path, TINY_TOML)
    results = tmp_path / "r"

    def limit():  # in the child: files may grow to 64 kB (a journal record is ~10 kB)
        resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, resource.RLIM_INFINITY))

    limited = subprocess.run([*CLI, "study", str(study_file), "--results", str(results), "--workers", "1",
                              "--quiet"], capture_output=True, text=True, timeout=300, preexec_fn=limit)
    assert limited.returncode == 2, limited.stderr
    assert limited.stderr.count("\n") == 1 and "ulimit -f" in limited.stderr, limited.stderr
    rerun = subprocess.run([*CLI, "study", str(study_file), "--results", str(results), "--workers", "1"],
                           capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    clean = tmp_path / "clean"
    run_study(small_study(sweep={"c3.eta": [5.0, 2.0]}), clean, workers=1)
    pd.testing.assert_frame_equal(tidy_metrics(results / "studies" / "tiny.h5"),
                                  tidy_metrics(clean / "studies" / "tiny.h5"), check_exact=True)


def test_a_local_cluster_that_does_not_start_is_one_line(tmp_path, monkeypatch):
    """Seen by killing both workers while the cluster started: Dask raised "Nanny failed to start"
    and the study printed a 220-line traceback."""
    import distributed

    from ilcforce.study import StudyRunError

    def failing(*args, **kwargs):
        raise RuntimeError("Nanny failed to start.\nworker process died")

    monkeypatch.setattr(distributed, "LocalCluster", failing)
    with pytest.raises(StudyRunError) as caught:
        run_study(small_study(), tmp_path, workers=2)
    assert str(caught.value) == ("the local Dask cluster of 2 workers did not start "
                                 "(RuntimeError: Nanny failed to start. worker process died)")


def test_ctrl_c_at_the_terminal_reaches_the_driver_not_the_workers(tmp_path):
    """A terminal's Ctrl-C goes to the whole process group: the local cluster's worker processes
    printed KeyboardInterrupt tracebacks from wherever it found them (found by an attack on the
    CLI). They now start with SIGINT ignored; the driver stops the study and the cluster."""
    study_file = write_study_file(tmp_path, TINY_TOML.replace('seeds = "0-1"', 'seeds = "0-5"'))
    results = tmp_path / "r"
    journal = results / "studies" / "tiny.h5.journal"
    driver = subprocess.Popen([*CLI, "study", str(study_file), "--results", str(results), "--workers", "2",
                               "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              start_new_session=True)  # its own process group, as a terminal's job
    try:
        _wait_for_a_committed_cell(driver, journal, lambda: "(stderr is read at the end)")
        os.killpg(driver.pid, signal.SIGINT)
        _, stderr = driver.communicate(timeout=60)
    finally:
        _stop(driver)
    assert driver.returncode == 130, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    assert stderr.splitlines()[0] == "interrupted: every finished cell is stored; rerun the same command to continue"
