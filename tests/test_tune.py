"""``ilcforce tune``: the tuning file (every problem one line), the objectives, the driver in-process,
on a LocalCluster and on a real Dask scheduler, resume after kill -9, validate, the tuned file.

Small on purpose (tests/tunekit.py): a 0.2 s horizon, 3 scored iterations, a check and a held-out
horizon of 9, 2 trials per method; the resume tests use a stand-in cell (arithmetic on the gains)
so that they time a kill, not physics.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.config_load import load_config
from ilcforce.tune import TuneError, TuningStoreError, build_tuning, load_tuning, run_tuning, validate_tuning
from ilcforce.tune.runner import read_trials
from ilcforce.tune.objectives import chattering_over, error_value, scored_means
from tunekit import EXPERIMENTS, ROOT, TINY, budget, fake_cell, only_c1, tiny_file, tiny_table, tuned

RANGE = {"low": 1.0, "high": 2.0}
C3 = {"eta": {"low": 0.0, "high": 1.0}}


@pytest.mark.parametrize("changes, message", [
    # the new format's own checks
    ({"cap": {"factor": 1.0}}, "tune.cap has no reference"),
    ({"cap": {"reference": "c2"}}, "tune.cap.reference 'c2' is not in tune.methods"),
    ({"cap": {"reference": "c1", "factor": 0.0}}, "tune.cap.factor must be above 0"),
    ({"cap": {"reference": "c1", "facter": 1.0}}, "unknown key tune.cap.facter (did you mean 'factor'?)"),
    ({"objective": "speed"}, "tune.objective: unknown objective 'speed'; choose from both, position, force"),
    ({"chattering": "effort"}, "tune.chattering: unknown chattering objective 'effort'; choose from settled-H"),
    ({"check_iterations": 8}, "tune.check_iterations must be at least 3 x tune.iterations = 9, got 8"),
    ({"heldout_iterations": 8}, "tune.heldout_iterations must be at least 3 x tune.iterations = 9, got 8"),
    ({"check_seeds": [1, 10]}, "tune.check_seeds shares seed 1 with tune.seeds"),
    ({"heldout_seeds": [0]}, "tune.heldout_seeds shares seed 0 with tune.seeds"),
    ({"heldout_seeds": "10-12"}, "tune.heldout_seeds shares seed 10 with tune.check_seeds"),
    ({"budget": {"bse": 3}}, "unknown key tune.budget.bse (did you mean 'base'?)"),
    ({"budget": {"stop_gain": 0.0}}, "tune.budget.stop_gain must be between 0 and 1"),
    ({"budget": {"stop_gain": 1.0}}, "tune.budget.stop_gain must be between 0 and 1"),
    ({"budget": {"stop_gain": -0.5}}, "tune.budget.stop_gain must be between 0 and 1"),
    ({"budget": {"base": 0}}, "tune.budget.base must be an integer >= 1"),
    ({"budget": {"per_dimension": -1}}, "tune.budget.per_dimension must be an integer in 0 .. 1000"),
    ({"budget": {"extend": 0}}, "tune.budget.extend must be an integer >= 1"),
    ({"budget": 3}, "[tune.budget] must be a table"),
    ({"check_iterations": None}, "tune.check_iterations is missing"),
    ({"cap": None}, "tune.cap is missing"),
    ({"heldout_seeds": None}, "tune.heldout_seeds is missing"),
    # the old format's keys are gone, by name
    ({"trials": 3}, "unknown key tune.trials"),
    ({"score_iterations": 4}, "unknown key tune.score_iterations"),
    # kept from before
    ({"methods": ["c9"]}, "unknown method 'c9'"),
    ({"seeds": "3-1"}, "tune.seeds range"),
    ({"score_last": 4}, "tune.score_last (4) must not exceed"),
    ({"iterations": 0}, "tune.iterations must be an integer >= 1"),
    ({"gains": {"c1": {"k": {"low": 10.0, "high": 1.0}}, "c3": C3}}, "tune.gains.c1.k: low must be below high"),
    ({"gains": {"c1": {"k": {"low": 1.0, "high": 1.0}}, "c3": C3}}, "tune.gains.c1.k: low must be below high"),
    ({"gains": {"c1": {"k": [RANGE, {"low": 5.0, "high": 4.0}]}, "c3": C3}}, "tune.gains.c1.k[1]: low must be below"),
    ({"gains": {"c1": {"k": {"low": 0.0, "high": 1.0, "log": True}}, "c3": C3}}, "a log range needs low > 0"),
    ({"gains": {"c1": {"kk": RANGE}, "c3": C3}}, "unknown gain tune.gains.c1.kk (did you mean 'k'?)"),
    ({"gains": {"c1": {"k": [RANGE]}, "c3": C3}}, "tune.gains.c1.k must list 2 entries"),
    ({"gains": {"c3": C3}}, "[tune.gains.c1] is missing"),
    ({"gains": {"c1": {"k": RANGE}, "c3": {"psi_acceleration": RANGE}}}, "is a choice, not a number"),
    ({"set": {"experiment.seed": 3}}, "experiment.seed is set by tune.seeds"),
    ({"set": {"reference.duration": -1.0}}, "reference.duration"),
])
def test_bad_tuning_file_names_the_key(changes, message):
    data = tiny_table(**changes)
    for key in [k for k, v in changes.items() if v is None]:
        del data["tune"][key]
    with pytest.raises(TuneError) as info:
        build_tuning(data)
    assert message in str(info.value) and "\n" not in str(info.value), str(info.value)


CLI_ERRORS = {  # (edit of the tiny file's text, what the one line says)
    "cap without a reference": (('reference = "c1"\n', ""), "tune.cap has no reference"),
    "cap reference not in methods": (('reference = "c1"', 'reference = "c2"'), "is not in tune.methods"),
    "unknown objective": (("sampler_seed = 0", 'sampler_seed = 0\nobjective = "speed"'), "unknown objective"),
    "unknown chattering objective": (("sampler_seed = 0", 'sampler_seed = 0\nchattering = "effort"'),
                                     "unknown chattering objective"),
    "an inverted range": (("low = 1.0, high = 1000.0", "low = 1000.0, high = 1.0"), "low must be below high"),
    "check horizon under 3x": (("check_iterations = 9", "check_iterations = 8"), "tune.check_iterations must be at least"),
    "held-out horizon under 3x": (("heldout_iterations = 9", "heldout_iterations = 6"),
                                  "tune.heldout_iterations must be at least"),
    "check seed scored": (("check_seeds = [10]", "check_seeds = [1]"), "tune.check_seeds shares seed 1 with tune.seeds"),
    "held-out seed scored": (("heldout_seeds = [90, 91]", "heldout_seeds = [0, 91]"), "shares seed 0 with tune.seeds"),
    "held-out seed checked": (("heldout_seeds = [90, 91]", "heldout_seeds = [10, 91]"),
                              "shares seed 10 with tune.check_seeds"),
    "unknown budget key": (("extend = 1", "extend = 1\ntrials = 4"), "unknown key tune.budget.trials"),
    "stop_gain at 1": (("stop_gain = 0.01", "stop_gain = 1.0"), "tune.budget.stop_gain must be between 0 and 1"),
    "stop_gain at 0": (("stop_gain = 0.01", "stop_gain = 0"), "tune.budget.stop_gain must be between 0 and 1"),
}


@pytest.mark.parametrize("case", list(CLI_ERRORS))
def test_cli_spec_error_is_one_line_on_stderr_exit_2(tmp_path, case):
    (old, new), message = CLI_ERRORS[case]
    assert old in TINY
    path = tiny_file(tmp_path, TINY.replace(old, new, 1))
    result = CliRunner().invoke(app, ["tune", str(path), "--results", str(tmp_path / "r")])
    assert result.exit_code == 2, result.output
    assert result.stdout == "" and result.stderr.startswith(f"error: {path}: ") and message in result.stderr, \
        result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr, result.stderr
    assert not (tmp_path / "r").exists()  # refused before any store was made


def test_cli_bad_tuning_file_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[tune]\nname = 'x'\n")
    result = CliRunner().invoke(app, ["tune", str(bad), "--results", str(tmp_path / "r")])
    assert result.exit_code == 2, result.output
    assert result.output.strip().splitlines() == [f"error: {bad}: tune.experiment is missing"], result.output
    missing = CliRunner().invoke(app, ["tune", str(tmp_path / "none.toml")])
    assert missing.exit_code == 2 and len(missing.output.strip().splitlines()) == 1, missing.output


def test_vector_gain_is_searched_element_wise_and_trial0_is_the_experiment():
    tuning = build_tuning(tiny_table())
    assert [n for n, _ in tuning.parameters("c3")] == ["k[0]", "eta"]
    assert [n for n, _ in tuning.parameters("c1")] == ["k[0]", "k[1]"]
    assert tuning.overrides("c3", {"k[0]": 3.0, "eta": 1.5}) == {"c3.k": [3.0, 100.0], "c3.eta": 1.5}
    assert tuning.default_params("c3") == {"k[0]": 10.0, "eta": 5.0}  # the paper's C3 gains
    assert tuning.defaults_in_space("c3") and tuning.defaults_in_space("c1")
    # the budget grows with the dimension
    assert tuning.first_budget("c1") == tuning.most_trials("c1") == 2
    wide = build_tuning(tiny_table(budget={"base": 4, "per_dimension": 3, "extend": 2}))
    assert (wide.first_budget("c1"), wide.most_trials("c1")) == (4 + 3 * 2, 2 * (4 + 3 * 2))
    # a fixed element other than the experiment's: trial 0 is not a point of the space
    changed = build_tuning(tiny_table(gains={"c1": {"k": [{"low": 1.0, "high": 1e3}, 7.0]},
                                             "c3": {"eta": {"low": 0.0, "high": 1.0}}}))
    assert not changed.defaults_in_space("c1")  # fixed 7 != the paper's 100
    assert not changed.defaults_in_space("c3")  # eta = 5 outside [0, 1]


def test_the_objectives_and_a_divergence_anywhere_in_the_horizon():
    tuning = build_tuning(tiny_table(iterations=3, score_last=2))
    ok = {"status": "complete", "position_error_rms": 1e-3, "force_error_rms": 0.1,
          "chattering_task_x_settled": 0.2, "chattering_task_y_settled": 0.05}
    rows = [dict(ok, iteration=j) for j in range(3)]
    means = scored_means(rows, tuning)
    assert means == pytest.approx({"e_p": 1e-3, "e_f": 0.1, "h_x": 0.2, "h_y": 0.05})
    assert error_value(means["e_p"], means["e_f"], "both") == pytest.approx(-1.0)  # log10(1 mm/1 mm) + log10(0.1 N/1 N)
    assert error_value(means["e_p"], means["e_f"], "position") == pytest.approx(0.0)
    assert error_value(means["e_p"], means["e_f"], "force") == pytest.approx(-1.0)
    # chattering: the worse axis against the cap; 0 is the cap's own
    assert chattering_over((0.2, 0.05), (0.2, 0.05)) == pytest.approx(0.0)
    assert chattering_over((0.2, 0.5), (0.2, 0.05)) == pytest.approx(1.0)
    assert chattering_over((0.02, 0.005), (0.2, 0.05)) == pytest.approx(-1.0)
    # only the scored iterations count
    assert scored_means([dict(ok, iteration=0, position_error_rms=1.0), *rows[1:]], tuning)["e_p"] == \
        pytest.approx(1e-3)
    assert scored_means(rows[:2], tuning) is None  # stopped before the horizon
    assert scored_means([dict(ok, iteration=0, status="diverged"), *rows[1:]], tuning) is None


def test_tiny_real_tuning_end_to_end(tmp_path):
    """A real tuning in-process: records validate; a rerun runs nothing and rewrites no byte; the
    held-out records exist and are sealed; a damaged one is refused by validate, then moved aside and
    run again by the next tune."""
    from ilcforce.store import records

    path = tiny_file(tmp_path)
    output = tmp_path / "exp" / "mine.toml"
    seen = []
    first = run_tuning(load_tuning(path), tmp_path / "r", workers=1, progress=seen.append)
    assert first.ran == 4 and first.skipped == 0 and first.scheduler == "in-process"
    assert sorted((p.method, p.number) for p in seen) == [("c1", 0), ("c1", 1), ("c3", 0), ("c3", 1)]
    assert all(p.trials == 2 for p in seen)
    summary = validate_tuning(first.path)
    assert {m: v[0] for m, v in summary["methods"].items()} == {"c1": 2, "c3": 2}
    trials = read_trials(first.path)
    assert trials["c3"][0]["gains"] == {"c3.k": [10.0, 100.0], "c3.eta": 5.0} and trials["c3"][0]["params"] == {}
    cap = trials["c1"][0]["cap"]
    # the reference against itself: about 0 (the cap is the median per axis, the objective the median of
    # each seed's worse axis)
    assert abs(trials["c1"][0]["chattering"]) < 0.1
    for method in ("c1", "c3"):
        for record in trials[method].values():
            assert record["cap"] == cap and len(record["checks"]) == 1
            assert record["checks"][0]["planned"] == 9 and record["checks"][0]["iterations_run"] == 9
    # held-out: trial 0 of each method and its front, on both held-out seeds, sealed
    heldout = sorted((first.path / "heldout").glob("*.json"))
    assert {f.name for f in heldout} >= {"c1-00000.json", "c3-00000.json"}
    for file in heldout:
        record = json.loads(file.read_text())
        assert [e["seed"] for e in record["seeds"]] == [90, 91]
        assert all(e["iterations_run"] == 9 for e in record["seeds"])
        assert records.seal({k: v for k, v in record.items() if k != "checksum"}) == record  # sealed
    # the tuned file: every chosen method's gains, the [tuning] table, the [tune.set] kept
    assert first.cap is not None and set(first.chosen) == {"c1", "c3"}
    config = load_config(first.tuned)
    assert first.tuned == first.path / "tuned.toml" and config.experiment.name == "tiny-tuned"
    assert config.reference.duration == 0.2 and config.experiment.iterations == 20
    assert config.tuning.source == "tiny"
    assert list(config.tuning.withheld) == [m for m in ("c1", "c3") if first.chosen[m] is None]
    for method, point in first.chosen.items():
        if point is not None:
            assert point["h_x"] <= first.cap[0] and point["h_y"] <= first.cap[1]
            for key, value in point["gains"].items():
                got = getattr(config.gains[method], key.split(".", 1)[1])
                assert (list(got) if isinstance(got, tuple) else got) == value, key
    # a rerun runs nothing and rewrites no byte
    files = [p for p in first.path.rglob("*") if p.is_file() and p.name != "tuning.json"]
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files}
    again = run_tuning(load_tuning(path), tmp_path / "r", workers=1)
    assert again.ran == 0 and again.skipped == 4 and again.chosen == first.chosen
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files} == before
    # -o: the same gains in an experiment named after the file, still nothing run
    named = run_tuning(load_tuning(path), tmp_path / "r", workers=1, output=output)
    assert named.ran == 0 and named.tuned == output and load_config(output).experiment.name == "mine"
    assert load_config(output).gains == config.gains
    # a damaged held-out record: validate refuses it in one line; the next tune moves it aside and reruns it
    target = first.path / "heldout" / "c3-00000.json"
    target.write_text(target.read_text().replace('"seed": 91', '"seed": 92'))
    result = CliRunner().invoke(app, ["validate", str(first.path)])
    assert result.exit_code == 2 and "c3-00000.json: refused (" in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    third = run_tuning(load_tuning(path), tmp_path / "r", workers=1)
    assert len(third.quarantined) == 1 and "c3-00000.json" in third.quarantined[0], third.quarantined
    assert (first.path / "heldout" / ".quarantine" / "c3-00000.json").is_file()
    assert third.ran == 0 and target.is_file() and third.chosen == first.chosen
    assert validate_tuning(first.path)["methods"] == summary["methods"]


def test_tiny_tuning_on_a_local_cluster_equals_in_process(tmp_path):
    tuning = load_tuning(tiny_file(tmp_path))
    cluster = run_tuning(tuning, tmp_path / "cluster", workers=2)
    assert cluster.ran == 4 and cluster.scheduler == "LocalCluster"
    alone = run_tuning(tuning, tmp_path / "alone", workers=1)
    a, b = read_trials(cluster.path), read_trials(alone.path)
    for method in tuning.methods:  # a cell is a pure function: the same trials, the same values
        for number in (0, 1):
            assert (a[method][number]["params"], a[method][number]["value"], a[method][number]["chattering"]) == \
                (b[method][number]["params"], b[method][number]["value"], b[method][number]["chattering"])
    assert cluster.chosen == alone.chosen and cluster.tuned.read_text() == alone.tuned.read_text()


def test_validate_refuses_a_gap_and_a_damaged_record(tmp_path):
    summary = tuned(tmp_path)
    first = summary.path / "trials" / "c3-00000.json"
    text = first.read_text()
    first.unlink()
    shutil.rmtree(summary.path / "heldout")  # else its held-out record, now of no stored trial, is named first
    with pytest.raises(TuningStoreError, match="c3's trial 0 is missing"):
        validate_tuning(summary.path)
    first.write_text(text.replace('"state": "complete"', '"state": "done"'))
    with pytest.raises(TuningStoreError, match="c3-00000.json: refused .its checksum does not match"):
        validate_tuning(summary.path)


def test_changed_search_is_refused_then_overwritten(tmp_path):
    tuned(tmp_path)
    other = TINY.replace("high = 1000.0", "high = 2000.0")
    with pytest.raises(TuningStoreError, match="another search"):
        tuned(tmp_path, other)
    summary = tuned(tmp_path, other, overwrite=True)
    assert summary.ran == 4 and summary.skipped == 0


# ------------------------------------------------------------------------------------------------
# resume: the stand-in cell makes trials instant; the sampler's choices are the only thing under test


RESUME_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from tunekit import fake_cell
from ilcforce.tune import load_tuning, run_tuning
run_tuning(load_tuning({file!r}), {results!r}, workers=1, cell_function=fake_cell)
"""


def test_resume_after_kill_9_repeats_no_finished_trial(tmp_path):
    path = tiny_file(tmp_path, budget(only_c1(), base=8))
    results = tmp_path / "results"
    script = RESUME_SCRIPT.format(tests=str(Path(__file__).parent), file=str(path), results=str(results))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "ILCFORCE_TEST_CELL_SLEEP": "0.1"}
    process = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    trials = results / "tuning" / "tiny" / "trials"
    # a hang guard, not a speed test: 3 trials of 0.1 s cells take about 1 s; 120 s leaves 100x for a loaded CI
    deadline = time.monotonic() + 120
    while not (trials.is_dir() and len(list(trials.glob("c1-*.json"))) >= 3):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.communicate()  # waits, and closes the pipes
    before = {f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in trials.glob("c1-*.json")}
    assert 3 <= len(before) < 8, before
    summary = run_tuning(load_tuning(path), results, workers=1, cell_function=fake_cell)
    assert summary.skipped == len(before) and summary.ran == 8 - len(before)
    after = {f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in trials.glob("c1-*.json")}
    assert {name: after[name] for name in before} == before  # no finished trial was written again
    assert validate_tuning(summary.path)["methods"]["c1"][0] == 8
    header = json.loads((summary.path / "tuning.json").read_text())
    assert len(header["sessions"]) == 2
    # and the resumed search asked what an uninterrupted one asks
    whole = run_tuning(load_tuning(path), tmp_path / "whole", workers=1, cell_function=fake_cell)
    assert [r["params"] for _, r in sorted(read_trials(whole.path)["c1"].items())] == \
        [r["params"] for _, r in sorted(read_trials(summary.path)["c1"].items())]
    assert whole.chosen == summary.chosen


def test_a_search_that_still_improves_runs_past_its_first_budget_and_a_resume_follows(tmp_path):
    """extend > 1: the search goes on while its front's hypervolume grows; a store cut short after
    its first budget resumes to exactly the trials of an uninterrupted run."""
    text = budget(only_c1(), base=4, extend=3)
    whole = tuned(tmp_path, text, results="whole")
    state = whole.searches["c1"]
    assert state["first"] == 4 and state["most"] == 12 and 4 <= state["trials"] <= 12
    assert state["converged"] or state["trials"] == 12
    stored = read_trials(whole.path)["c1"]
    assert sorted(stored) == list(range(state["trials"]))
    # cut after the first budget, then resumed
    parts = tuned(tmp_path, text, results="parts")
    for number in range(4, state["trials"]):
        (parts.path / "trials" / f"c1-{number:05d}.json").unlink()
    for file in (parts.path / "heldout").glob("*.json"):
        file.unlink()
    resumed = tuned(tmp_path, text, results="parts")
    assert resumed.ran == state["trials"] - 4 and resumed.searches["c1"] == state
    assert [r["params"] for _, r in sorted(read_trials(resumed.path)["c1"].items())] == \
        [r["params"] for _, r in sorted(stored.items())]


def test_a_changed_budget_is_another_search(tmp_path):
    """The budget is part of what defines a search (how far each method goes depends on it): a stored
    tuning refuses a changed one until --overwrite, in one line, and keeps its trials."""
    tuned(tmp_path, budget(base=2))
    with pytest.raises(TuningStoreError, match="defines another search.*--overwrite"):
        tuned(tmp_path, budget(base=3))
    summary = tuned(tmp_path, budget(base=2))
    assert summary.ran == 0 and summary.skipped == 4


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
        assert remote.chosen == local.chosen
    finally:
        for process in (worker, scheduler):
            if process is not None:
                process.terminate()
                try:
                    process.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()


def test_an_unreachable_scheduler_is_one_line_and_leaves_no_store(tmp_path):
    path = tiny_file(tmp_path)
    results = tmp_path / "r"
    result = CliRunner().invoke(app, ["tune", str(path), "--results", str(results), "--scheduler",
                                      f"tcp://127.0.0.1:{_free_port()}", "--timeout", "2"])
    assert result.exit_code == 2, result.output
    assert result.output.strip().startswith("error: cannot reach the Dask scheduler") and \
        len(result.output.strip().splitlines()) == 1, result.output
    assert not (results / "tuning" / "tiny").exists()


def test_gains_the_setting_refuses_fail_their_trial_with_the_reason(tmp_path):
    # PD-ILC's Q cutoff must stay below the Nyquist frequency of the 0.1 ms control period (5 kHz)
    text = only_c1(budget(base=4)).replace('methods = ["c1"]', 'methods = ["c1", "pd-ilc"]')
    text += "[tune.gains.pd-ilc]\nk = { low = 1.0, high = 1000.0, log = true }\nq_cutoff = { low = 4000.0, high = 9000.0 }\n"
    tuning = load_tuning(tiny_file(tmp_path, text))
    assert not tuning.defaults_in_space("pd-ilc")  # the default 5 Hz lies outside: trial 0 scored, not told
    summary = tuned(tmp_path, text)
    trials = read_trials(summary.path)["pd-ilc"]
    assert trials[0]["state"] == "complete" and not trials[0]["in_sampler"]
    refused = [r for r in trials.values() if r["state"] == "failed"]
    assert refused and all("Nyquist" in r["message"] and r["seeds"] == [] and r["checks"] == [] for r in refused)
    assert all(r["gains"]["pd-ilc.q_cutoff"] >= 5000.0 and not r["feasible"] for r in refused)


def test_the_tuned_file_gives_each_method_the_gains_its_trials_ran():
    """C3-leak's gains extend C3's (a key set in [c3] reaches C3-leak unless C3-leak sets it): the
    tuned file must give C3-leak the Gamma its own trials ran with, not C3's tuned one."""
    import tomllib

    from ilcforce.tune.output import tuned_experiment

    data = tiny_table(methods=["c1", "c3", "c3-leak"], gains={"c1": {"k": RANGE}, "c3": {"eta": {"low": 1.0, "high": 9.0}},
                                                              "c3-leak": {"eta": {"low": 1.0, "high": 9.0}}})
    tuning = build_tuning(data)
    tuned_gamma = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    point = {"trial": 1, "e_p": 1e-4, "e_f": 0.1, "h_x": 0.1, "h_y": 0.1}
    chosen = {"c1": None, "c3": {**point, "gains": {"c3.gamma": tuned_gamma, "c3.eta": 2.0}},
              "c3-leak": {**point, "gains": {"c3-leak.eta": 3.0}}}
    document = tomllib.loads(tuned_experiment(tuning, chosen, {}, (0.2, 0.3)))
    ran = load_config(EXPERIMENTS / "paper.toml", {"c3-leak.eta": 3.0}).gains["c3-leak"]
    assert document["c3"]["gamma"] == tuned_gamma and document["c3"]["eta"] == 2.0
    assert document["c3-leak"]["gamma"] == list(ran.gamma) != tuned_gamma
    assert document["c3-leak"]["eta"] == 3.0
    assert document["tuning"]["source"] == "tiny" and document["tuning"]["withheld"] == ["c1"]


def test_tune_help_shows_the_tune_table():
    result = CliRunner().invoke(app, ["tune", "--help"], env={"COLUMNS": "200"})
    assert "[tune]" in result.output, result.output
