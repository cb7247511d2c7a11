"""Shared pieces of the tuning tests (tests/test_tune*.py): a tiny tuning file and a stand-in cell.

The tiny tuning: a 0.2 s reference, 3 scored iterations on 2 seeds, a check of 9 (3x) on one seed,
9 held-out iterations on 2 seeds, C1 (the cap's reference) and C3, 2 trials each (base 2,
per_dimension 0, extend 1). :func:`fake_cell` stands in for :func:`ilcforce.study.cell.run_cell`
with arithmetic on the gains (instant, deterministic): the error falls and the chattering rises with
k[0], so a search has a real front; the tests that use it time files and processes, not physics.
"""

from __future__ import annotations

import os
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXPERIMENTS = ROOT / "experiments"

TINY = f"""
[tune]
name = "tiny"
experiment = "{EXPERIMENTS / 'paper.toml'}"
methods = ["c1", "c3"]
seeds = [0, 1]
iterations = 3
score_last = 2
check_seeds = [10]
check_iterations = 9
heldout_seeds = [90, 91]
heldout_iterations = 9
sampler_seed = 0
[tune.budget]
base = 2
per_dimension = 0
extend = 1
stop_gain = 0.01
[tune.cap]
reference = "c1"
factor = 1.0
[tune.set]
"reference.duration" = 0.2
[tune.gains.c1]
k = {{ low = 1.0, high = 1000.0, log = true }}
[tune.gains.c3]
k = [{{ low = 1.0, high = 100.0, log = true }}, 100.0]
eta = {{ low = 0.0, high = 10.0 }}
"""


def budget(text: str = TINY, base: int = 2, per_dimension: int = 0, extend: int = 1) -> str:
    """``text`` with another [tune.budget]."""
    return (text.replace("base = 2", f"base = {base}").replace("per_dimension = 0", f"per_dimension = {per_dimension}")
            .replace("extend = 1", f"extend = {extend}"))


def only_c1(text: str = TINY) -> str:
    """``text`` searching C1 alone (the cap's reference)."""
    text = text.replace('methods = ["c1", "c3"]', 'methods = ["c1"]')
    return text[:text.index("[tune.gains.c3]")]


def tiny_file(tmp_path: Path, text: str = TINY, file: str = "tiny.toml") -> Path:
    path = tmp_path / file
    path.write_text(text)
    return path


def tiny_table(**changes) -> dict:
    data = tomllib.loads(TINY)
    data["tune"].update(changes)
    return data


def fake_cell(config, method, keep_store=None, stop=None):
    """Rows of arithmetic on the gains: e_P = 1 mm x (1 + 100 / k[0]), e_F = 0.1 N + 0.01 N x seed,
    settled H_x = 1 mN x k[0], H_y = 50 mN; honours ``stop`` as run_cell does."""
    k = config.gains[method].k[0]
    time.sleep(float(os.environ.get("ILCFORCE_TEST_CELL_SLEEP", "0")))
    rows = []
    for j in range(config.experiment.iterations):
        rows.append({"iteration": j, "status": "complete", "position_error_rms": 1e-3 * (1 + 100.0 / k),
                     "force_error_rms": 0.1 + 0.01 * config.experiment.seed,
                     "chattering_task_x_settled": 1e-3 * k, "chattering_task_y_settled": 0.05})
        if stop is not None and stop(rows):
            break
    return {"rows": rows, "elapsed": 0.0, "worker": "test"}


def failing_cell(config, method, keep_store=None, stop=None):
    """C3 diverges at iteration 1 whatever its gains; C1 as :func:`fake_cell`."""
    result = fake_cell(config, method, keep_store, stop)
    if method == "c3":
        result["rows"][1]["status"] = "diverged"
    return result


def tuned(tmp_path: Path, text: str = TINY, results: str = "r", cell=fake_cell, **kwargs):
    """``run_tuning`` of ``text`` in-process with the stand-in cell."""
    from ilcforce.tune import load_tuning, run_tuning

    return run_tuning(load_tuning(tiny_file(tmp_path, text)), tmp_path / results, workers=1, cell_function=cell,
                      **kwargs)
