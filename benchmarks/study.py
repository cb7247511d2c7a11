"""Study speed and scale figures for ``make bench`` (never a timed test).

* the paper's Monte Carlo (``experiments/paper-mc.toml``: 100 seeds x c1, c2, c3 x 20 iterations)
  on the default LocalCluster, metrics only: wall time from a cold driver, split into cluster
  start-up and cells;
* the per-cell overhead: (workers x wall of the cell phase - sum of the cells' own compute time) /
  sum of compute time: scheduling, transfer, the driver's writes and idle workers;
* driver and worker memory (RSS) at 10% of the cells and at the end (flat in the number of cells
  means the two agree);
* the speed-up from 1 worker (in-process) to 2 LocalCluster workers on a smaller study, runs
  alternated, medians: of the cell phase (from the moment every worker has loaded the kernels, as
  the runner does before the first cell) and of the whole run including the cluster's start.
"""

from __future__ import annotations

import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

from ilcforce.study import load_study, read_study, run_study
from ilcforce.study.spec import parse_seeds

PAPER_MC = Path(__file__).resolve().parents[1] / "experiments" / "paper-mc.toml"


def _rss_mb() -> tuple[float, float]:
    """(driver RSS, largest child-process RSS) in MB."""
    import psutil

    me = psutil.Process()
    children = [p.memory_info().rss for p in me.children(recursive=True) if p.is_running()]
    return me.memory_info().rss / 1e6, max(children, default=0) / 1e6


def timed_study(seeds: int, workers: int, study_file: Path = PAPER_MC) -> dict:
    """Run ``study_file`` with ``seeds`` seeds on ``workers`` (1: in-process) in a temporary folder."""
    study = load_study(study_file)
    study = dataclasses.replace(study, seeds=parse_seeds(f"0-{seeds - 1}"))
    marks: dict = {"memory": []}
    n_cells = len(study.cells())

    def progress(p) -> None:
        now = time.perf_counter()
        if p.last == "":
            marks["ready"] = now
        done = p.finished + p.failed
        if done in (max(1, n_cells // 10), n_cells):
            marks["memory"].append(_rss_mb())
        if done == n_cells and p.last:
            marks["last"] = now  # the last cell committed (the cluster's shutdown comes after)

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        summary = run_study(study, tmp, workers=workers, progress=progress)
        end = time.perf_counter()
        compute = float(read_study(summary.path).cells["elapsed"].sum())
    ready = marks.get("ready", start)
    cell_wall = marks.get("last", end) - ready
    return {"wall": end - start, "startup": ready - start, "cell_wall": cell_wall, "compute": compute,
            "cells": n_cells, "failed": len(summary.failed),
            "overhead": (workers * cell_wall - compute) / compute if compute > 0 else float("nan"),
            "memory": marks["memory"]}


def main(mc_seeds: int = 100, speedup_seeds: int = 10, repeat: int = 3, workers: int = 2) -> None:
    if mc_seeds > 0:
        r = timed_study(mc_seeds, workers)
        print(f"  paper Monte Carlo, {mc_seeds} seeds x 3 methods x 20 iterations ({r['cells']} cells, "
              f"{r['failed']} failed), LocalCluster x {workers}, metrics only: {r['wall']:8.1f} s wall "
              f"(cluster start {r['startup']:.1f} s, cells {r['cell_wall']:.1f} s)")
        print(f"  per-cell overhead (scheduling, transfer, driver writes, idle)   : {100 * r['overhead']:8.1f} % "
              f"of the cells' compute ({r['compute'] / r['cells']:.2f} s per cell)")
        if len(r["memory"]) == 2:
            (d1, w1), (d2, w2) = r["memory"]
            print(f"  memory at 10% / 100% of the cells: driver {d1:.0f} / {d2:.0f} MB, largest worker "
                  f"{w1:.0f} / {w2:.0f} MB")
    if speedup_seeds > 0:
        one, two = [], []
        for _ in range(repeat):  # alternated, so that load changes hit both alike
            one.append(timed_study(speedup_seeds, 1)["cell_wall"])
            two.append(timed_study(speedup_seeds, 2)["cell_wall"])
        m1, m2 = statistics.median(one), statistics.median(two)
        pairs = sorted(a / b for a, b in zip(one, two))
        print(f"  speed-up 1 -> 2 workers ({speedup_seeds} seeds x 3 methods, cell phase on warm workers, medians "
              f"of {repeat}): {m1:.1f} s (in-process) -> {m2:.1f} s (LocalCluster x 2) = {m1 / m2:.2f}x "
              f"(run pairs {pairs[0]:.2f}-{pairs[-1]:.2f}x)")
        c1, c2 = cold_study_walls(speedup_seeds, repeat)
        print(f"  the same as a user runs it (cold `ilcforce study --workers 1|2 --quiet`, whole command): "
              f"{c1:.1f} s -> {c2:.1f} s = {c1 / c2:.2f}x")


def cold_study_walls(seeds: int, repeat: int) -> tuple[float, float]:
    """Median wall of the real command, cold, with 1 (in-process) and 2 workers (alternated)."""
    import subprocess
    import sys

    from benchmarks.cold import entry_point

    walls: dict[int, list[float]] = {1: [], 2: []}
    with tempfile.TemporaryDirectory() as tmp:
        study = Path(tmp) / "speedup.toml"
        study.write_text(f'[study]\nname = "speedup"\nexperiment = "{PAPER_MC.parent / "paper.toml"}"\n'
                         f'methods = ["c1", "c2", "c3"]\nseeds = "0-{seeds - 1}"\n')
        for i in range(repeat):
            for workers in (1, 2):
                start = time.perf_counter()
                subprocess.run([*entry_point(), "study", str(study), "--workers", str(workers), "--quiet",
                                "--results", str(Path(tmp) / f"r{i}-{workers}")], check=True,
                               stdout=subprocess.DEVNULL, stderr=sys.stderr)
                walls[workers].append(time.perf_counter() - start)
    return statistics.median(walls[1]), statistics.median(walls[2])
