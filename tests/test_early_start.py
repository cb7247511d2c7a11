"""``ilcforce simulate`` started before typer parses (ilcforce.early_start): only a plain command line
starts early, a run is taken only by the command it was started for, and what it stores is the
numbers of a run started the usual way."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from ilcforce import aot, early_start, experiment
from ilcforce.config_load import load_config
from storekit import assert_same_datasets, assert_same_records

needs_aot = pytest.mark.skipif(aot.module() is None, reason="early start runs only the ahead-of-time kernels")
SHORT = ["--set", "reference.duration=0.2"]


@pytest.fixture(autouse=True)
def nothing_started_left():
    early_start.drop()
    yield
    early_start.drop()


@pytest.mark.parametrize("args, expected", [
    (["simulate"], {"method": "c3", "sets": []}),
    (["simulate", "--method", "c1", "--iters=5", "-o", "x.h5", "--set", "c3.eta=2", "--set", "a=b c",
      "--overwrite", "--seed", "7", "--results", "r", "-c", "e.toml"],
     {"method": "c1", "iters": 5, "out": "x.h5", "sets": ["c3.eta=2", "a=b c"], "overwrite": True, "seed": 7,
      "results": "r", "config": "e.toml"}),
    (["simulate", "-m", "c2", "-m", "c3", "-n", "2"], {"method": "c3", "iters": 2, "sets": []}),  # the last counts
])
def test_a_plain_simulate_line_is_read(args, expected):
    assert early_start.read_arguments(args) == expected


@pytest.mark.parametrize("args", [
    [], ["compare"], ["--help"], ["simulate", "--help"], ["simulate", "--resume"], ["simulate", "extra"],
    ["simulate", "--iters"], ["simulate", "--iters", "-3"], ["simulate", "--iters", "x"], ["simulate", "-n=3"],
    ["simulate", "--overwrite=1"], ["simulate", "--out", "-"], ["simulate", "--out="], ["simulate", "--methods", "c1"],
    ["simulate", "--iters", "0x10"],
])
def test_anything_else_is_left_to_the_parser(args):
    assert early_start.read_arguments(args) is None
    assert early_start.begin(args) is False
    assert early_start._started is None


@pytest.mark.parametrize("args", [
    ["simulate", "--method", "nope"], ["simulate", "--set", "c3.nonsense=1"], ["simulate", "--iters", "0"],
    ["simulate", "--config", "/nonexistent/e.toml"],
])
def test_a_faulty_line_starts_nothing_and_raises_nothing(args):
    assert early_start.begin(args) is False
    assert early_start._started is None


def test_a_fifo_config_is_not_read_early(tmp_path):
    fifo = tmp_path / "e.toml"
    os.mkfifo(fifo)
    t0 = time.monotonic()
    assert early_start.begin(["simulate", "--config", str(fifo)]) is False  # would block if it opened it
    assert time.monotonic() - t0 < 5


@needs_aot
def test_the_command_takes_the_run_started_for_it_and_it_is_the_same_run():
    assert early_start.begin(["simulate", "--iters", "3", *SHORT, "--set", "plant.perturbation.from_iteration=2"])
    config = load_config(None, {"reference.duration": 0.2, "plant.perturbation.from_iteration": 2,
                                "experiment.iterations": 3})
    run = early_start.take(config, "c3")
    assert run is not None and early_start.take(config, "c3") is None  # only once
    with run:
        early = list(run.records())
    assert_same_records(early, list(experiment.simulate_iterations(config, "c3")))


@needs_aot
@pytest.mark.parametrize("method, overrides, resume", [
    ("c3", {"experiment.iterations": 51}, False),  # another configuration
    ("c1", {"experiment.iterations": 50}, False),  # another method
    ("c3", {"experiment.iterations": 50}, True),  # a resumed run needs its store's memory
])
def test_another_run_does_not_take_it_and_it_is_stopped(method, overrides, resume):
    assert early_start.begin(["simulate", "--iters", "50"])  # about a second of simulation
    started = early_start._started
    assert started._ahead._thread.is_alive()
    assert early_start.take(load_config(None, overrides), method, resume=resume) is None
    assert not started._ahead._thread.is_alive()  # stopped (within one chunk) and joined


@needs_aot
def test_run_method_refuses_a_run_started_for_another(tmp_path, short_config):
    started = experiment.start_iterations(short_config(), "c3")
    with pytest.raises(ValueError, match="started for another run"):
        experiment.run_method(short_config(), "c1", tmp_path / "c1.h5", started=started)
    assert not started._ahead._thread.is_alive()
    assert not (tmp_path / "c1.h5").exists()


_TAKEN = """\
import sys
from ilcforce import early_start
take = early_start.take
def recorded(*args, **kwargs):
    run = take(*args, **kwargs)
    print("TAKEN" if run is not None else "NOT TAKEN", file=sys.stderr, flush=True)
    return run
early_start.take = recorded
sys.argv = ["ilcforce", *sys.argv[1:]]
from ilcforce._entry import main
main()
"""


@needs_aot
def test_the_entry_point_starts_a_plain_simulate_early_and_stores_what_the_library_does(tmp_path, short_config):
    script = tmp_path / "entry.py"
    script.write_text(_TAKEN)
    out = tmp_path / "cli" / "c3.h5"
    proc = subprocess.run([sys.executable, str(script), "simulate", "--iters", "3", *SHORT, "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "TAKEN" in proc.stderr and "NOT TAKEN" not in proc.stderr
    library = tmp_path / "library" / "c3.h5"
    experiment.run_method(short_config(), "c3", library)
    assert_same_datasets(out, library)


@needs_aot
def test_an_existing_store_refused_stops_the_early_run_and_keeps_the_store(tmp_path, short_config):
    out = tmp_path / "c3.h5"
    experiment.run_method(short_config(), "c3", out)
    before = out.read_bytes()
    proc = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "--iters", "3", *SHORT, "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert out.read_bytes() == before
