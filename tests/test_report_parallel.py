"""The report's speed-ups change no number: the per-seed array lookups answer as the DataFrame
readers do, the pool returns results in order and forwards its workers' progress, and a report
written on two processes is byte for byte the one written in one."""

from __future__ import annotations

import math
import os
import signal
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ilcforce.stops import STOPS, stop_signals
from ilcforce.report import pool, tables
from ilcforce.report.seedframes import SeedMetrics, split_seeds


def _frame(statuses: list[str], iterations: list[int], seed: int = 0, method: str = "c3") -> pd.DataFrame:
    rng = np.random.default_rng(len(statuses) * 7 + seed)
    n = len(statuses)
    return pd.DataFrame({"seed": seed, "method": method, "iteration": iterations, "status": statuses,
                         "diverged_time": [0.3 if s == "diverged" else math.nan for s in statuses],
                         "position_error_2norm": rng.uniform(1e-6, 1e-4, n),
                         "force_error_2norm": np.where(rng.uniform(size=n) < 0.2, np.nan, rng.uniform(0.01, 1, n)),
                         "chattering_task_x": rng.uniform(0.01, 0.1, n)})


CASES = {
    "complete": (["complete"] * 20, list(range(20))),
    "diverged at 12": (["complete"] * 12 + ["diverged"], list(range(13))),
    "diverged at 3, stored out of order": (["diverged", "complete", "complete", "complete"], [3, 2, 0, 1]),
    "gap and a partial iteration": (["complete"] * 9 + ["partial"] + ["complete"] * 5, [*range(9), 10, 9, *range(11, 15)]),
    "nothing complete": (["diverged"], [0]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_seed_metrics_answer_as_the_dataframe_readers(case):
    statuses, iterations = CASES[case]
    tidy = _frame(statuses, iterations)
    frame = tidy.drop(columns=["seed", "method"]).set_index("iteration").sort_index()
    fast = split_seeds(tidy)[0]["c3"]
    assert fast.divergence == tables.divergence(frame) or (
        fast.divergence[0] == tables.divergence(frame)[0] and math.isnan(fast.divergence[1]))
    assert fast.complete_iterations == tables.complete_iterations(frame)
    assert fast.chattering_iteration() == tables.chattering_iteration(frame)
    for column in ("position_error_2norm", "force_error_2norm", "chattering_task_x", "no_such_column"):
        if column != "no_such_column":
            assert fast.jbar(column) == tables.jbar(frame, column)
        for j in range(-1, 22):
            ours, theirs = fast.value_at(column, j), tables.value_at(frame, column, j)
            assert ours == theirs or (math.isnan(ours) and math.isnan(theirs)), (column, j)
    again = SeedMetrics.from_frame(frame)
    assert again.complete_iterations == fast.complete_iterations and again.divergence == fast.divergence


def test_split_seeds_keeps_every_seed_and_method_in_ascending_seed_order():
    tidy = pd.concat([_frame(["complete"] * 3, [2, 0, 1], seed=s, method=m) for s in (5, 1, 3) for m in ("c3", "c1")])
    split = split_seeds(tidy.sample(frac=1.0, random_state=0))  # rows shuffled
    assert list(split) == [1, 3, 5]
    for seed, by_method in split.items():
        assert set(by_method) == {"c1", "c3"}
        assert by_method["c1"].iterations == [0, 1, 2]
        rows = tidy[(tidy["seed"] == seed) & (tidy["method"] == "c1")].sort_values("iteration")
        np.testing.assert_array_equal(by_method["c1"].columns["position_error_2norm"], rows["position_error_2norm"])
    assert split_seeds(tidy.iloc[:0]) == {}


def _square(x: int, progress=None) -> int:
    if progress is not None:
        progress(f"squaring {x}")
    if x < 0:
        raise ValueError(f"negative {x}")
    return x * x


@pytest.mark.parametrize("jobs", [1, 2])
def test_pool_returns_results_in_task_order_and_forwards_progress(jobs):
    tasks = [pool.Task(f"task {x}", _square, (x,), cost=float(x % 3)) for x in range(6)]
    lines: list[str] = []
    assert pool.run_tasks(tasks, jobs=jobs, progress=lines.append) == [x * x for x in range(6)]
    assert sorted(line for line in lines if line.startswith("squaring")) == [f"squaring {x}" for x in range(6)]
    done = [line for line in lines if " done (" in line]
    assert len(done) == 6 and done[-1].endswith("(6 of 6)")


def test_pool_raises_a_task_error_here():
    tasks = [pool.Task("fine", _square, (2,)), pool.Task("bad", _square, (-1,))]
    with pytest.raises(ValueError, match="negative -1"):
        pool.run_tasks(tasks, jobs=2)


class _Worker:
    """A pool worker stand-in; terminating the first one delivers a stop signal to this process."""

    def __init__(self, signal_on_terminate: int | None) -> None:
        self.signal_on_terminate, self.alive, self.joined = signal_on_terminate, True, False

    def is_alive(self) -> bool:
        return self.alive

    def terminate(self) -> None:
        self.alive = False
        if self.signal_on_terminate is not None:
            os.kill(os.getpid(), self.signal_on_terminate)

    kill = terminate

    def join(self, timeout=None) -> None:
        self.joined = True


class _Pool:
    def __init__(self, workers) -> None:
        self._processes = dict(enumerate(workers))

    def shutdown(self, wait=True, cancel_futures=False) -> None:
        pass


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_second_stop_while_workers_are_ended_ends_every_worker_first(signum):
    """A second Ctrl-C arriving while a stopped report ended its workers raised at once, in the
    middle of the loop, and left the workers not yet terminated running, orphaned. Now it is
    answered (the command stops, exit 130 / 143) only after every worker is ended."""
    workers = [_Worker(signum), _Worker(None), _Worker(None)]
    with stop_signals():
        with pytest.raises(KeyboardInterrupt):
            pool._end_workers(_Pool(workers), grace=0.0)
        assert STOPS == [signum]
    assert not any(w.alive for w in workers) and all(w.joined for w in workers)


_STOPPED_POOL = """
import os, sys, time
from pathlib import Path
from ilcforce.stops import stop_signals
from ilcforce.report import pool

def piece(i, progress=None):
    Path(sys.argv[1], str(os.getpid())).write_text("")
    time.sleep(60)

tasks = [pool.Task(str(i), piece, (i,)) for i in range(6)]
with stop_signals():
    try:
        pool.run_tasks(tasks, jobs=2)
    except KeyboardInterrupt:
        print("stopped", flush=True)
        sys.exit(143)
"""


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_stopped_report_ends_at_once_and_leaves_no_worker(tmp_path, signum):
    """Stopping `ilcforce report` mid-way waited for every queued piece (the pool's shutdown runs
    them all) and left its forked workers running, orphaned, ignoring SIGTERM. Now the stop ends
    the command within seconds and every worker with it."""
    import subprocess
    import sys

    with subprocess.Popen([sys.executable, "-c", _STOPPED_POOL, str(tmp_path)], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True) as proc:
        deadline = time.monotonic() + 60
        while len(list(tmp_path.iterdir())) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = [int(p.name) for p in tmp_path.iterdir()]
        assert len(workers) == 2, "the pool's two workers did not start"
        sent = time.monotonic()
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=30)
        took = time.monotonic() - sent
    assert proc.returncode == 143 and out.strip() == "stopped", (proc.returncode, out, err)
    assert took < 5.0, f"the stop took {took:.1f} s"
    assert "Traceback" not in err, err
    for pid in workers:
        assert not _alive(pid), f"worker {pid} outlived the command"


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"
