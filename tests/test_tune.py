"""``ilcforce tune``: the tuning file, the driver in-process, on a LocalCluster and on a real Dask
scheduler, the tuning store (resume after kill -9, validate), the tuned experiment file.

Small on purpose: a 0.2 s horizon, 3 iterations, 2 seeds, 2-3 trials per method; the resume
tests use a stand-in cell (pure arithmetic on the gains) so that they time a kill, not physics.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.config_load import load_config
from ilcforce.tune import TuneError, TuningStoreError, build_tuning, load_tuning, run_tuning, validate_tuning
from ilcforce.tune.spec import seed_score
from ilcforce.tune.runner import read_trials

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
ROOT = Path(__file__).resolve().parent.parent

TINY = f"""
[tune]
name = "tiny"
experiment = "{EXPERIMENTS / 'paper.toml'}"
methods = ["c2", "c3"]
seeds = [0, 1]
iterations = 3
score_last = 2
trials = 2
sampler_seed = 0
[tune.set]
"reference.duration" = 0.2
[tune.gains.c2]
k = {{ low = 100.0, high = 1000.0, log = true }}
[tune.gains.c3]
k = [{{ low = 1.0, high = 100.0, log = true }}, 100.0]
eta = {{ low = 0.0, high = 10.0 }}
"""


def tiny_file(tmp_path: Path, text: str = TINY, file: str = "tiny.toml") -> Path:
    path = tmp_path / file
    path.write_text(text)
    return path


def tiny_table(**changes) -> dict:
    import tomllib

    data = tomllib.loads(TINY)
    data["tune"].update(changes)
    return data


@pytest.mark.parametrize("changes, message", [
    ({"trials": 0}, "tune.trials must be an integer >= 1"),
    ({"methods": ["c9"]}, "unknown method 'c9'"),
    ({"seeds": "3-1"}, "tune.seeds range"),
    ({"score_iterations": 4}, "must not exceed tune.iterations"),
    ({"score_last": 4}, "tune.score_last (4) must not exceed"),
    ({"objective": "speed"}, "tune.objective must be one of both, position, force"),
    ({"trails": 3}, "unknown key tune.trails (did you mean 'trials'?)"),
    ({"gains": {"c2": {"k": {"low": 10.0, "high": 1.0}}, "c3": {"eta": {"low": 0, "high": 1}}}},
     "tune.gains.c2.k: low must be below high"),
    ({"gains": {"c2": {"k": {"low": 0.0, "high": 1.0, "log": True}}, "c3": {"eta": {"low": 0, "high": 1}}}},
     "a log range needs low > 0"),
    ({"gains": {"c2": {"kk": {"low": 1.0, "high": 2.0}}, "c3": {"eta": {"low": 0, "high": 1}}}},
     "unknown gain tune.gains.c2.kk (did you mean 'k'?)"),
    ({"gains": {"c2": {"k": [{"low": 1.0, "high": 2.0}]}, "c3": {"eta": {"low": 0, "high": 1}}}},
     "tune.gains.c2.k must list 2 entries"),
    ({"gains": {"c3": {"eta": {"low": 0, "high": 1}}}}, "[tune.gains.c2] is missing"),
    ({"gains": {"c2": {"k": {"low": 1.0, "high": 2.0}}, "c3": {"psi_acceleration": {"low": 0, "high": 1}}}},
     "is a choice, not a number"),
    ({"set": {"experiment.seed": 3}}, "experiment.seed is set by tune.seeds"),
    ({"set": {"reference.duration": -1.0}}, "reference.duration"),
])
def test_bad_tuning_file_names_the_key(changes, message):
    with pytest.raises(TuneError) as info:
        build_tuning(tiny_table(**changes))
    assert message in str(info.value) and "\n" not in str(info.value), str(info.value)


def test_cli_bad_tuning_file_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[tune]\nname = 'x'\n")
    result = CliRunner().invoke(app, ["tune", str(bad), "--results", str(tmp_path / "r")])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert lines == [f"error: {bad}: tune.experiment is missing"], result.output
    missing = CliRunner().invoke(app, ["tune", str(tmp_path / "none.toml")])
    assert missing.exit_code == 2 and len(missing.output.strip().splitlines()) == 1, missing.output


def test_vector_gain_is_searched_element_wise_and_trial0_is_the_experiment():
    tuning = build_tuning(tiny_table())
    assert [n for n, _ in tuning.parameters("c3")] == ["k[0]", "eta"]
    assert [n for n, _ in tuning.parameters("c2")] == ["k[0]", "k[1]"]
    assert tuning.overrides("c3", {"k[0]": 3.0, "eta": 1.5}) == {"c3.k": [3.0, 100.0], "c3.eta": 1.5}
    assert tuning.default_params("c3") == {"k[0]": 10.0, "eta": 5.0}  # the paper's C3 gains
    assert tuning.defaults_in_space("c3") and tuning.defaults_in_space("c2")
    # a fixed element other than the experiment's: trial 0 is not a point of the space
    changed = build_tuning(tiny_table(gains={"c2": {"k": [{"low": 1.0, "high": 1e3}, 7.0]},
                                             "c3": {"eta": {"low": 0.0, "high": 1.0}}}))
    assert not changed.defaults_in_space("c2")  # fixed 7 != the paper's 400
    assert not changed.defaults_in_space("c3")  # eta = 5 outside [0, 1]


def test_seed_score_fails_a_divergence_anywhere_in_the_horizon():
    tuning = build_tuning(tiny_table(iterations=4, score_iterations=3, score_last=2))
    ok = {"status": "complete", "position_error_rms": 1e-3, "force_error_rms": 0.1}
    rows = [dict(ok, iteration=j) for j in range(4)]
    assert seed_score(rows, tuning) == pytest.approx(-1.0)  # log10(1 mm / 1 mm) + log10(0.1 N / 1 N)
    assert seed_score(rows[:3], tuning) is None  # stopped before the horizon
    late = [*rows[:3], dict(ok, iteration=3, status="diverged")]
    assert seed_score(late, tuning) is None  # diverged after the scored iterations: still a failure


def test_tiny_tuning_on_a_local_cluster_and_its_tuned_file(tmp_path):
    tuning = load_tuning(tiny_file(tmp_path))
    seen = []
    summary = run_tuning(tuning, tmp_path / "results", workers=2, progress=seen.append)
    assert summary.ran == 4 and summary.skipped == 0 and summary.scheduler == "LocalCluster"
    assert sorted((p.method, p.number) for p in seen) == [("c2", 0), ("c2", 1), ("c3", 0), ("c3", 1)]
    trials = read_trials(summary.path)
    assert trials["c3"][0]["gains"] == {"c3.k": [10.0, 100.0], "c3.eta": 5.0}  # trial 0: the experiment's gains
    assert trials["c3"][0]["params"] == {}
    for method, best in summary.best.items():
        assert best is not None
        values = [r["value"] for r in trials[method].values() if r["value"] is not None]
        assert best[1] == min(values) <= trials[method][0]["value"]  # never worse than trial 0
    assert validate_tuning(summary.path)["methods"]["c2"][0] == 2
    # the tuned file is an experiment file `simulate -c` loads, carrying each method's best gains
    config = load_config(summary.tuned)
    for method, (number, _value) in summary.best.items():
        for key, value in trials[method][number]["gains"].items():
            field = key.split(".", 1)[1]
            got = getattr(config.gains[method], field)
            assert (list(got) if isinstance(got, tuple) else got) == value, key
    # the tuning's [tune.set] is kept (the gains were judged under it), the experiment's iterations too
    assert config.reference.duration == 0.2 and config.experiment.iterations == 20
    assert config.experiment.name == "tiny-tuned"
    named = run_tuning(tuning, tmp_path / "results", workers=1, output=tmp_path / "exp" / "mine.toml")
    assert named.ran == 0 and load_config(named.tuned).experiment.name == "mine"  # experiments/<stem>.toml
    # the same trial in-process gives the same value (the cell is a pure function)
    again = run_tuning(tuning, tmp_path / "inproc", workers=1)
    assert {m: read_trials(again.path)[m][1]["value"] for m in tuning.methods} == \
        {m: trials[m][1]["value"] for m in tuning.methods}


def test_validate_refuses_a_gap_and_a_damaged_record(tmp_path):
    tuning = load_tuning(tiny_file(tmp_path))
    summary = run_tuning(tuning, tmp_path / "r", workers=1)
    first = summary.path / "trials" / "c2-00000.json"
    text = first.read_text()
    first.unlink()
    with pytest.raises(TuningStoreError, match="c2's trial 0 is missing"):
        validate_tuning(summary.path)
    first.write_text(text.replace('"state": "complete"', '"state": "done"'))
    with pytest.raises(TuningStoreError, match="c2-00000.json: refused .its checksum does not match"):
        validate_tuning(summary.path)


def test_changed_search_is_refused_then_overwritten(tmp_path):
    run_tuning(load_tuning(tiny_file(tmp_path)), tmp_path / "r", workers=1)
    other = load_tuning(tiny_file(tmp_path, TINY.replace("high = 1000.0", "high = 2000.0"), "other.toml"))
    with pytest.raises(TuningStoreError, match="another search"):
        run_tuning(other, tmp_path / "r", workers=1)
    summary = run_tuning(other, tmp_path / "r", workers=1, overwrite=True)
    assert summary.ran == 4 and summary.skipped == 0


# ------------------------------------------------------------------------------------------------
# resume: a stand-in cell whose "errors" are arithmetic on the gains, so trials are instant and the
# sampler's choices are the only thing under test


def fake_cell(config, method, keep_store=None):
    gains = config.gains[method]
    k = gains.k[0]
    time.sleep(float(os.environ.get("ILCFORCE_TEST_CELL_SLEEP", "0")))
    rows = [{"iteration": j, "status": "complete", "position_error_rms": 1e-3 * (1 + (k - 300.0) ** 2 / 1e4),
             "force_error_rms": 0.1 + 0.01 * config.experiment.seed} for j in range(config.experiment.iterations)]
    return {"rows": rows, "elapsed": 0.0, "worker": "test"}


def test_extending_the_budget_asks_what_one_run_would_have_asked(tmp_path):
    path = tiny_file(tmp_path, TINY.replace("trials = 2", "trials = 6"))
    whole = run_tuning(load_tuning(path), tmp_path / "whole", workers=1, cell_function=fake_cell)
    short = tiny_file(tmp_path, TINY.replace("trials = 2", "trials = 3"), "short.toml")
    run_tuning(load_tuning(short), tmp_path / "parts", workers=1, cell_function=fake_cell)
    resumed = run_tuning(load_tuning(path), tmp_path / "parts", workers=1, cell_function=fake_cell)
    assert resumed.skipped == 6 and resumed.ran == 6
    a, b = read_trials(whole.path), read_trials(resumed.path)
    assert {m: {n: r["params"] for n, r in t.items()} for m, t in a.items()} == \
        {m: {n: r["params"] for n, r in t.items()} for m, t in b.items()}


RESUME_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from test_tune import fake_cell
from ilcforce.tune import load_tuning, run_tuning
run_tuning(load_tuning({file!r}), {results!r}, workers=1, cell_function=fake_cell)
"""


def test_resume_after_kill_9_repeats_no_finished_trial(tmp_path):
    one_method = TINY.replace('methods = ["c2", "c3"]', 'methods = ["c2"]').replace("trials = 2", "trials = 8")
    path = tiny_file(tmp_path, one_method[:one_method.index("[tune.gains.c3]")])
    results = tmp_path / "results"
    script = RESUME_SCRIPT.format(tests=str(Path(__file__).parent), file=str(path), results=str(results))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "ILCFORCE_TEST_CELL_SLEEP": "0.15"}
    process = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    trials = results / "tuning" / "tiny" / "trials"
    deadline = time.monotonic() + 120
    while not (trials.is_dir() and len(list(trials.glob("c2-*.json"))) >= 3):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.communicate()  # waits, and closes the pipes
    before = {f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in trials.glob("c2-*.json")}
    assert 3 <= len(before) < 8, before
    summary = run_tuning(load_tuning(path), results, workers=1, cell_function=fake_cell)
    assert summary.skipped == len(before) and summary.ran == 8 - len(before)
    after = {f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in trials.glob("c2-*.json")}
    assert {name: after[name] for name in before} == before  # no finished trial was written again
    assert validate_tuning(summary.path)["methods"]["c2"][0] == 8
    header = json.loads((summary.path / "tuning.json").read_text())
    assert len(header["sessions"]) == 2
    # and the resumed search asked what an uninterrupted one asks
    whole = run_tuning(load_tuning(path), tmp_path / "whole", workers=1, cell_function=fake_cell)
    assert [r["params"] for _, r in sorted(read_trials(whole.path)["c2"].items())] == \
        [r["params"] for _, r in sorted(read_trials(summary.path)["c2"].items())]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_tuning_on_a_real_dask_scheduler(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    scheduler = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                  "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = None
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline and scheduler.poll() is None, "dask scheduler did not start"
                time.sleep(0.1)
        worker = subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nworkers", "1", "--nthreads", "1",
                                   "--host", "127.0.0.1", "--no-dashboard"],
                                  env={**os.environ, "PYTHONPATH": str(ROOT)},
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        tuning = load_tuning(tiny_file(tmp_path))
        remote = run_tuning(tuning, tmp_path / "remote", scheduler=address)
        assert remote.ran == 4 and remote.scheduler == address
        local = run_tuning(tuning, tmp_path / "local", workers=1)
        assert read_trials(remote.path)["c3"][1]["value"] == read_trials(local.path)["c3"][1]["value"]
    finally:
        for process in (worker, scheduler):
            if process is not None:
                process.terminate()
                try:
                    process.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()


@pytest.mark.parametrize("name", ["fivebar-tune", "serial2r-tune"])
def test_shipped_tuning_files_load_and_start_from_the_shipped_gains(name):
    tuning = load_tuning(EXPERIMENTS / "tuning" / f"{name}.toml")
    assert tuning.name == name
    from ilcforce.controllers import REGISTRY

    assert set(tuning.methods) == set(REGISTRY)  # every method, one budget
    for method in tuning.methods:  # the sampler learns from trial 0 (the experiment's gains)
        assert tuning.defaults_in_space(method), method


def test_trials_frame_and_its_figure(tmp_path):
    from matplotlib.figure import Figure

    from ilcforce.report.tuning import plot_tuning_history
    from ilcforce.report.tuning import trials_frame

    path = tiny_file(tmp_path, TINY.replace("trials = 2", "trials = 4"))
    summary = run_tuning(load_tuning(path), tmp_path / "r", workers=1, cell_function=fake_cell)
    frame = trials_frame(summary.path)
    assert len(frame) == 8 and list(frame.columns[:7]) == ["method", "trial", "state", "objective", "best_so_far",
                                                             "message", "elapsed"]
    c2 = frame[frame["method"] == "c2"].sort_values("trial")
    assert list(c2["best_so_far"]) == list(np.minimum.accumulate(c2["objective"]))
    assert c2["best_so_far"].iloc[-1] == summary.best["c2"][1]
    ax = Figure().add_subplot()
    artists = plot_tuning_history(ax, frame, "c2")
    assert len(artists) == 3  # trials, best so far, trial 0 ringed (no failed trial here)


def test_an_unreachable_scheduler_is_one_line_and_leaves_no_store(tmp_path):
    path = tiny_file(tmp_path)
    results = tmp_path / "r"
    result = CliRunner().invoke(app, ["tune", str(path), "--results", str(results), "--scheduler",
                                      f"tcp://127.0.0.1:{_free_port()}", "--timeout", "2"])
    assert result.exit_code == 2, result.output
    assert result.output.strip().startswith("error: cannot reach the Dask scheduler") and \
        len(result.output.strip().splitlines()) == 1, result.output
    assert not (results / "tuning" / "tiny").exists()


def test_the_report_has_a_tuning_page_per_store_and_warns_on_a_damaged_one(tmp_path):
    import pandas as pd

    from ilcforce.report.tuning import tuning_pages

    path = tiny_file(tmp_path, TINY.replace("trials = 2", "trials = 3"))
    results = tmp_path / "results"
    summary = run_tuning(load_tuning(path), results, workers=1, cell_function=fake_cell)
    written, warnings = [], []
    lines = tuning_pages(results, tmp_path / "report", ("png",), written, warnings)
    page = tmp_path / "report" / "tuning" / "tiny"
    assert warnings == [] and {p.name for p in written} >= {"index.md", "history.png", "tuning.csv"}
    table = pd.read_csv(page / "tuning.csv")
    assert list(table["method"]) == ["c2", "c3"] and list(table["trials"]) == ["3 of 3", "3 of 3"]
    assert table.set_index("method").loc["c2", "best objective"] == pytest.approx(summary.best["c2"][1])
    assert lines[0].startswith("- [tuning tiny](tuning/tiny/index.md): c2 ")
    (summary.path / "trials" / "c3-00001.json").write_text("{")  # a damaged record: a warning, not a crash
    lines = tuning_pages(results, tmp_path / "report2", ("png",), [], warnings)
    assert lines == [] and len(warnings) == 1 and "c3-00001.json" in warnings[0]


def test_gains_the_setting_refuses_fail_their_trial_with_the_reason(tmp_path):
    # PD-ILC's Q cutoff must stay below the Nyquist frequency of the 0.1 ms control period (5 kHz)
    text = TINY.replace('methods = ["c2", "c3"]', 'methods = ["pd-ilc"]').replace("trials = 2", "trials = 4")
    text = text[:text.index("[tune.gains.c2]")] + "[tune.gains.pd-ilc]\nq_cutoff = { low = 4000.0, high = 9000.0 }\n"
    tuning = load_tuning(tiny_file(tmp_path, text))
    assert not tuning.defaults_in_space("pd-ilc")  # the default 5 Hz lies outside: trial 0 scored, not told
    summary = run_tuning(tuning, tmp_path / "r", workers=1, cell_function=fake_cell)
    trials = read_trials(summary.path)["pd-ilc"]
    assert trials[0]["state"] == "complete" and not trials[0]["in_sampler"]
    refused = [r for r in trials.values() if r["state"] == "failed"]
    assert refused and all("Nyquist" in r["message"] and r["seeds"] == [] for r in refused)
    assert all(r["gains"]["pd-ilc.q_cutoff"] >= 5000.0 for r in refused)
    assert summary.best["pd-ilc"][1] == min(r["value"] for r in trials.values() if r["value"] is not None)


def test_the_tuned_file_gives_each_method_the_gains_its_trials_ran():
    """C3-leak's gains extend C3's (a key set in [c3] reaches C3-leak unless C3-leak sets it): the
    tuned file must give C3-leak the Gamma its own trials ran with, not C3's tuned one."""
    import tomllib

    from ilcforce.tune.output import tuned_experiment

    data = tiny_table(methods=["c3", "c3-leak"], gains={"c3": {"eta": {"low": 1.0, "high": 9.0}},
                                                        "c3-leak": {"eta": {"low": 1.0, "high": 9.0}}})
    tuning = build_tuning(data)
    tuned_gamma = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    best = {"c3": {"number": 1, "value": -5.0, "gains": {"c3.gamma": tuned_gamma, "c3.eta": 2.0}},
            "c3-leak": {"number": 1, "value": -4.0, "gains": {"c3-leak.eta": 3.0}}}
    document = tomllib.loads(tuned_experiment(tuning, best))
    ran = load_config(EXPERIMENTS / "paper.toml", {"c3-leak.eta": 3.0}).gains["c3-leak"]
    assert document["c3"]["gamma"] == tuned_gamma and document["c3"]["eta"] == 2.0
    assert document["c3-leak"]["gamma"] == list(ran.gamma) != tuned_gamma
    assert document["c3-leak"]["eta"] == 3.0
