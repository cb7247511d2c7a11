"""The README's Python API example runs as written, on a store written by the CLI; and the run
object reads back exactly what was stored."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ilcforce
from ilcforce import store

README = Path(__file__).resolve().parents[1] / "README.md"
SHORT = ["--set", "reference.duration=0.2"]


def _example() -> str:
    text = README.read_text(encoding="utf-8")
    match = re.search(r"<!-- python-api-example[^>]*-->\s*```python\n(.*?)```", text, re.S)
    assert match, "README has no marked Python API example"
    return match.group(1)


def test_readme_python_api_example_runs(tmp_path: Path):
    out = tmp_path / "results" / "paper" / "c3.h5"
    made = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-m", "c3", "-n", "2", "--out", str(out),
                           *SHORT], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    result = subprocess.run([sys.executable, "-c", _example()], cwd=tmp_path, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    assert "N s^1/2" in result.stdout and "theta_hat_D11" in result.stdout and "0.0001" in result.stdout


def test_run_object_reads_back_what_is_stored(tmp_path: Path):
    out = tmp_path / "c3.h5"
    made = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-m", "c3", "-n", "2", "--out", str(out),
                           *SHORT], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    run = ilcforce.open(out)
    assert run.iterations == [0, 1] and run.method == "c3"
    record = run.iteration(1)
    frame = record.to_pandas()
    np.testing.assert_array_equal(frame["position_x"].to_numpy(), record.log["position"][:, 0])
    assert frame.attrs["units"]["position_x"] == "m"
    memory = run.memory(1)
    stored = store.read_memory(out, 1)
    np.testing.assert_array_equal(memory.filter(like="theta_hat_").to_numpy(), stored["theta_hat"])
    assert list(memory.filter(like="theta_hat_").columns) == [f"theta_hat_{n}" for n in ("D11", "D12", "C11", "C12", "D21", "D22", "C21", "C22")]
    assert memory.index[1] == run.config.simulation.sample_time
    np.testing.assert_array_equal(record.memory["alpha_hat"], stored["alpha_hat"])
    assert run.metrics.equals(store.read_metrics(out))


def test_a_run_object_shows_the_file_as_it_is_now(tmp_path: Path):
    """A run object read its iterations and metrics once and kept them: a store extended by another
    process (``simulate --resume``, or a run still going) showed the old numbers in a notebook. It
    now reads again when the file has changed, and only then."""
    out = tmp_path / "c3.h5"

    def simulate(*extra: str) -> None:
        made = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-m", "c3", "--out", str(out), *SHORT,
                               *extra], capture_output=True, text=True, timeout=300)
        assert made.returncode == 0, made.stderr

    simulate("-n", "2")
    run = ilcforce.open(out)
    assert run.iterations == [0, 1] and len(run.metrics) == 2
    before = run.metrics
    assert run.metrics is not before and run.metrics.equals(before)  # a copy: editing it changes nothing here
    before.loc[0, "position_error_2norm"] = -1.0
    assert run.metrics.loc[0, "position_error_2norm"] > 0
    simulate("-n", "3", "--resume")
    assert run.iterations == [0, 1, 2]
    assert run.metrics.equals(store.read_metrics(out)) and len(run.metrics) == 3
    assert run.provenance["run_state"] == "complete" and run.config.experiment.iterations == 3


def test_every_public_name_resolves_and_import_ilcforce_loads_nothing_heavy():
    """``ilcforce.__all__`` is what a notebook imports (docs/api.md): each name resolves to the
    object it names, and ``import ilcforce`` alone loads none of numpy, pandas, h5py or numba."""
    import subprocess
    import sys

    import ilcforce
    from ilcforce.controllers import REGISTRY
    from ilcforce.study import tidy_metrics

    for name in ilcforce.__all__:
        assert getattr(ilcforce, name) is not None, name
    assert ilcforce.METHODS is REGISTRY and ilcforce.tidy_metrics is tidy_metrics
    assert "c3" in ilcforce.METHODS and "serial2r" in ilcforce.PLANTS
    code = "import sys, ilcforce\nprint(*(m for m in ('numpy', 'pandas', 'h5py', 'numba') if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == "", done.stdout + done.stderr


def test_notebook_spellings(tmp_path: Path):
    """What a notebook user types first works: len(run), iteration over a run, run.iteration(-1) and
    run[-1] (negative indices count from the last stored iteration, as Python lists do), and the
    gains as attributes of the configuration."""
    out = tmp_path / "c3.h5"
    made = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-m", "c3", "-n", "3", "--out", str(out),
                           *SHORT, "--set", "c3.eta=2"], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    run = ilcforce.open(out)
    assert len(run) == 3
    assert [record.iteration for record in run] == [0, 1, 2]
    assert run.iteration(-1).iteration == 2 and run.iteration(-3).iteration == 0 and run[-2].iteration == 1
    np.testing.assert_array_equal(run.iteration(-1).log["position"], run.iteration(2).log["position"])
    assert run.memory(-1).equals(run.memory(2))
    assert run.config.c3 is run.config.gains["c3"] and run.config.c3.eta == 2.0
    assert run.config.smc_bl is run.config.gains["smc-bl"] and "smc_bl" in dir(run.config)
    with pytest.raises(store.StoreError, match=r"iteration -4 is not stored \(3 iterations stored\)"):
        run.iteration(-4)
    with pytest.raises(IndexError, match="iteration 3 is not stored"):
        run[3]
    with pytest.raises(AttributeError, match="methods' gains: c1, c2, c3"):
        run.config.c9


def test_a_python_caller_is_told_the_keyword_not_the_flag(tmp_path: Path, short_config):
    """An existing store refused to ilcforce.run_method names overwrite=True and resume=True (the
    command line's refusal names --overwrite and --resume)."""
    import ilcforce
    from ilcforce.store import StoreExistsError

    config = short_config(**{"experiment.iterations": 1})
    path = tmp_path / "c1.h5"
    ilcforce.run_method(config, "c1", path)
    with pytest.raises(StoreExistsError) as refused:
        ilcforce.run_method(config, "c1", path)
    message = str(refused.value)
    assert "overwrite=True" in message and "resume=True" in message and "--" not in message, message
    ilcforce.run_method(config, "c1", path, overwrite=True)  # and the keyword does what it says
