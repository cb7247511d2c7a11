"""The tuning store held to the run and study stores' standard: every defect an attack on the tuning
store found, reproduced with real files and processes. Forged and damaged records are named by
`validate`, skipped by readers, moved aside with one line by the next `tune`, never fed to the
optimiser and never shipped; a resume never overwrites a finished trial and refills gaps; `tune -o`
never overwrites unasked; outputs say what happened.

The trials run a stand-in cell (arithmetic on the gains, :func:`test_tune.fake_cell`): these tests
time files and processes, not physics.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.store import records
from ilcforce.store.tuning import TuningStore, TuningStoreError
from ilcforce.tune.runner import read_trials
from ilcforce.tune import TuneError, load_tuning, run_tuning, validate_tuning
from tunekit import ROOT, TINY, budget, fake_cell, failing_cell, tiny_file, tuned as _tuned

TRIALS = budget(base=4)


def tuned(tmp_path, text=TRIALS, results="r", **kwargs):
    return _tuned(tmp_path, text, results, **kwargs)


def reseal(path: Path, change) -> None:
    """Change a stored record and seal it again: a forgery a checksum alone cannot catch."""
    record = json.loads(path.read_text())
    change(record)
    record.pop("checksum")
    path.write_text(json.dumps(records.seal(record)))


def validate_cli(path) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["validate", str(path)])
    return result.exit_code, result.output


FORGERIES = {
    "objective edited to -99": lambda r: r.update(value=-99.0),
    "chattering edited to -99": lambda r: r.update(chattering=-99.0),
    "value disagrees with its seeds": lambda r: r["seeds"][0].update(value=r["seeds"][0]["value"] - 1.0),
    "seed value and objective both edited": lambda r: (r["seeds"][0].update(value=-99.0),
                                                       r["seeds"][1].update(value=-99.0), r.update(value=-99.0)),
    "seed chattering and chattering both edited": lambda r: (r["seeds"][0].update(chattering=-9.0),
                                                             r["seeds"][1].update(chattering=-9.0),
                                                             r.update(chattering=-9.0)),
    "a stored norm edited": lambda r: r["seeds"][0]["position_error_rms"].__setitem__(-1, 1e-9),
    "cap edited": lambda r: r.update(cap=[c * 10 for c in r["cap"]]),
    "feasible flipped": lambda r: r.update(feasible=False),
    "check flagged but feasible": lambda r: r["checks"][0].update(verdict="flagged"),
    "check diverged but feasible": lambda r: r["checks"][0].update(diverged_iteration=4),
    "a check run cut short but feasible": lambda r: r["checks"][0].update(iterations_run=5),
    "a check run planned shorter": lambda r: r["checks"][0].update(planned=5, iterations_run=5),
    "a check seed the tuning does not run": lambda r: r["checks"][0].update(seed=11),
    "a check entry without its fields": lambda r: r["checks"][0].pop("planned"),
    "gains differ from its params": lambda r: r["gains"].update({"c1.k": [1e6, 1e6]}),
    "param out of range": lambda r: r["params"].update({"k[0]": 1e6}),
    "param missing": lambda r: r["params"].pop("k[0]"),
    "param of the wrong type": lambda r: r["params"].update({"k[0]": "abc"}),
    "gains not a table": lambda r: r.update(gains="abc"),
    "value true": lambda r: r.update(value=True),
    "value NaN": lambda r: r.update(value=float("nan")),
    "value -Infinity": lambda r: r.update(value=float("-inf")),
    "another search's id": lambda r: r.update(tuning="0" * 32),
    "another search's digest": lambda r: r.update(search="0" * 64),
    "a seed the tuning does not run": lambda r: r["seeds"][0].update(seed=7),
    "a seed true for 1": lambda r: r["seeds"][1].update(seed=True),
    "number beyond every budget": lambda r: r.update(number=40),
    "error norms not a list": lambda r: r["seeds"][0].update(position_error_rms=5),
    "a seed's entry without its fields": lambda r: r["seeds"][0].pop("iterations_run"),
    # issue 46 item 7: a seed carrying a "message" skipped the check of its values against its norms
    "seeds carrying a message, values forged": lambda r: (r["seeds"][0].update(message="x", value=-99.0),
                                                         r["seeds"][1].update(message="x", value=-99.0),
                                                         r.update(value=-99.0)),
    "a failed seed's entry (no norms) with a value": lambda r: (
        r["seeds"][0].update(message="the worker died", iterations_run=0, value=-99.0,
                             **{k: [] for k in ("position_error_rms", "force_error_rms", "chattering_task_x_settled",
                                                "chattering_task_y_settled")}),
        r.update(value=(r["seeds"][1]["value"] - 99.0) / 2)),  # the median of the two seeds' values
    "a seed carrying an empty message": lambda r: r["seeds"][0].update(message=""),
    "failed although every seed scored": lambda r: r.update(state="failed", value=None, chattering=None,
                                                           feasible=False),
}


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """One tuning of TRIALS, run once: each test gets a copy (:func:`copy_of`)."""
    where = tmp_path_factory.mktemp("stored")
    return tuned(where)


def copy_of(stored, tmp_path):
    """A copy of the ``stored`` tuning where :func:`tuned` of ``tmp_path`` finds it."""
    shutil.copytree(stored.path, tmp_path / "r" / "tuning" / "tiny")
    return stored


@pytest.mark.parametrize("forgery", list(FORGERIES))
def test_a_forged_record_is_named_skipped_quarantined_and_never_shipped(tmp_path, forgery, stored):
    first = copy_of(stored, tmp_path)
    first = dataclasses.replace(first, path=tmp_path / "r" / "tuning" / "tiny")
    beyond = forgery == "number beyond every budget"
    name = "c1-00002.json" if not beyond else "c1-00040.json"
    target = first.path / "trials" / name
    if beyond:
        shutil.copy(first.path / "trials" / "c1-00002.json", target)
    reseal(target, FORGERIES[forgery])
    code, output = validate_cli(first.path)
    assert code == 2 and f"{name}: refused (" in output and len(output.strip().splitlines()) == 1, output
    assert (2 in read_trials(first.path)["c1"]) == beyond and 40 not in read_trials(first.path)["c1"]
    again = tuned(tmp_path)  # the next writer moves it aside, says so, reruns its trial
    # (and its held-out evaluation, if it had one: it evaluates a trial no longer stored)
    assert any(name in line for line in again.quarantined), again.quarantined
    assert all(name in line or "heldout/c1-00002.json" in line for line in again.quarantined), again.quarantined
    assert (first.path / "trials" / ".quarantine" / name).is_file()
    assert again.ran == (0 if beyond else 1)
    assert validate_tuning(again.path)["methods"]["c1"][0] == 4
    assert again.chosen == first.chosen  # the rerun trial is what it was: the forgery changed nothing
    text = again.tuned.read_text()
    assert "1000000" not in text and "1e+06" not in text and "-99" not in text


def test_a_forged_held_out_record_is_refused_quarantined_and_rerun(tmp_path, stored):
    copy_of(stored, tmp_path)
    first = tuned(tmp_path)
    target = first.path / "heldout" / "c1-00000.json"
    reseal(target, lambda r: r.update(gains={"c1.k": [1e6, 1e6]}))  # gains not the trial's: refused
    code, output = validate_cli(first.path)
    assert code == 2 and "heldout/c1-00000.json: refused (it evaluates c1 trial 0" in output, output
    assert len(output.strip().splitlines()) == 1, output
    again = tuned(tmp_path)
    assert [line for line in again.quarantined if "c1-00000.json" in line] == list(again.quarantined) != []
    assert again.ran == 0 and again.chosen == first.chosen and again.cap == first.cap
    assert json.loads(target.read_text())["gains"] == {"c1.k": [10.0, 100.0]}


def test_any_one_digit_change_in_any_file_of_a_tuning_store_is_refused(tmp_path):
    first = tuned(tmp_path, TINY)
    files = [first.path / "tuning.json", first.path / "tuned.toml", *sorted((first.path / "trials").glob("*.json")),
             *sorted((first.path / "heldout").glob("*.json"))]
    assert len(files) > 6
    changed = 0
    for file in files:
        data = file.read_bytes()
        for at in range(0, len(data), max(1, len(data) // 40)):  # about 40 places a file, every kind of field
            if not chr(data[at]).isdigit():
                continue
            digit = b"7" if data[at:at + 1] != b"7" else b"3"
            changed_data = data[:at] + digit + data[at + 1:]
            if file.suffix == ".json" and json.loads(changed_data) == json.loads(data):
                continue  # the 17th digit of a float: the same number, no change
            file.write_bytes(changed_data)
            with pytest.raises(TuningStoreError):
                validate_tuning(first.path)
            changed += 1
        file.write_bytes(data)
    assert changed > 50
    assert validate_tuning(first.path)["methods"]["c1"][0] == 2


def _duplicate_value(data: bytes) -> bytes:
    """Issue 46 item 8: a second "value" key before the real one (Python keeps the last, so the parsed
    record and its seal were unchanged; a reader that keeps the first sees -99)."""
    return data.replace(b'{', b'{"value": -99.0, ', 1)


def _duplicate_name(data: bytes) -> bytes:
    return data.replace(b'{', b'{"name": "other", ', 1)


@pytest.mark.parametrize("file, change", [("trials/c1-00002.json", _duplicate_value),
                                          ("tuning.json", _duplicate_name),
                                          ("trials/c3-00001.json", lambda d: d.replace(b'"seeds": [{',
                                                                                      b'"seeds": [{"seed": 5, ', 1))])
def test_a_key_named_twice_in_a_record_is_refused(tmp_path, stored, file, change):
    copy_of(stored, tmp_path)
    path = tmp_path / "r" / "tuning" / "tiny"
    target = path / file
    data = target.read_bytes()
    target.write_bytes(change(data))
    assert json.loads(target.read_bytes()) == json.loads(data)  # the same to Python: the seal held before
    code, output = validate_cli(path)
    assert code == 2 and "appears twice in one object" in output and len(output.strip().splitlines()) == 1, output


def test_what_the_seal_covers_is_the_parsed_record(tmp_path, stored):
    """The seal covers the canonical JSON of the record as parsed (docs/store-format.md): whitespace, key
    order and escapes that leave every value the same are no change to any reader and are accepted; the
    values read are the record's."""
    copy_of(stored, tmp_path)
    path = tmp_path / "r" / "tuning" / "tiny"
    target = path / "trials" / "c1-00002.json"
    record = json.loads(target.read_bytes())
    before = read_trials(path)["c1"][2]
    reordered = dict(reversed(list(record.items())))
    text = json.dumps(reordered, indent=3).replace('"complete"', '"\u0063omplete"')
    assert '"\u0063omplete"' in text
    target.write_text(text)
    code, output = validate_cli(path)
    assert code == 0, output
    assert read_trials(path)["c1"][2] == before


def test_hard_linked_and_symlinked_records_of_another_store_are_refused(tmp_path):
    one, other = tuned(tmp_path, results="one"), tuned(tmp_path, results="two")
    (one.path / "trials" / "c1-00003.json").unlink()
    os.link(other.path / "trials" / "c1-00003.json", one.path / "trials" / "c1-00003.json")
    assert "another tuning store" in validate_cli(one.path)[1]
    (one.path / "trials" / "c1-00003.json").unlink()
    (one.path / "trials" / "c1-00003.json").symlink_to(other.path / "trials" / "c1-00003.json")
    assert "a symbolic link" in validate_cli(one.path)[1]


def test_a_trial_copied_from_another_tuning_or_to_another_number_is_refused(tmp_path):
    """A JSON editor's splice: a trial file copied from another tuning store of the same search, its
    checksum recomputed; a trial copied to another number of the same store, its checksum recomputed.
    The record names its store's id and its number; neither is this place's."""
    one, other = tuned(tmp_path, results="one"), tuned(tmp_path, results="two")
    target = one.path / "trials" / "c1-00003.json"
    shutil.copyfile(other.path / "trials" / "c1-00003.json", target)
    reseal(target, lambda r: None)
    code, output = validate_cli(one.path)
    assert code == 2 and "another tuning store" in output and len(output.strip().splitlines()) == 1, output
    shutil.copyfile(one.path / "trials" / "c1-00002.json", target)
    reseal(target, lambda r: None)
    code, output = validate_cli(one.path)
    assert code == 2 and "not the trial of its file name" in output, output


@pytest.mark.parametrize("where", ["record", "header"])
def test_deep_json_is_refused_in_bounded_time(tmp_path, where):
    first = tuned(tmp_path, TINY)
    target = first.path / ("trials/c3-00001.json" if where == "record" else "tuning.json")
    target.write_text("[" * 100_000 + "]" * 100_000)
    start = time.monotonic()
    code, output = validate_cli(first.path)
    assert code == 2 and "nested too deeply" in output and len(output.strip().splitlines()) == 1, output
    result = subprocess.run([sys.executable, "-m", "ilcforce", "tune", str(tiny_file(tmp_path, TINY)), "--results",
                             str(tmp_path / "r"), "--workers", "1", "-q"], capture_output=True, text=True,
                            timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT)})
    if where == "header":
        assert result.returncode == 2 and "nested too deeply" in result.stderr, result.stderr
        assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    else:
        assert result.returncode == 0 and "c3-00001.json: refused (JSON nested too deeply)" in result.stderr
    # bounded, not fast: an unbounded parse of 100,000 levels never returns (or overflows the stack); both
    # commands take about 2 s here, so 300 s is a hang guard with 100x to spare on a loaded machine
    assert "Traceback" not in result.stderr and time.monotonic() - start < 300


def test_a_fifo_in_the_store_never_hangs_a_reader(tmp_path):
    first = tuned(tmp_path, TINY)
    (first.path / "tuned.toml").unlink()
    os.mkfifo(first.path / "tuned.toml")
    assert "tuned.toml: not the tuned file the last run wrote" in validate_cli(first.path)[1]
    (first.path / "tuned.toml").unlink()
    (first.path / "trials" / "c1-00001.json").unlink()
    os.mkfifo(first.path / "trials" / "c1-00001.json")
    os.mkfifo(first.path / "trials" / "notes")  # not a record's name: never opened
    result = subprocess.run([sys.executable, "-m", "ilcforce", "validate", str(first.path)], capture_output=True,
                            text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 2 and "c1-00001.json: refused (not a regular file)" in result.stdout + result.stderr


def test_a_gap_is_refilled_and_no_finished_trial_is_written_again(tmp_path):
    first = tuned(tmp_path, budget(base=6))
    trials = first.path / "trials"
    kept = {f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in trials.glob("c1-*.json") if f.name != "c1-00002.json"}
    before = read_trials(first.path)["c1"]
    (trials / "c1-00002.json").unlink()
    again = tuned(tmp_path, budget(base=6))
    assert again.ran == 1 and again.skipped == 11
    after = {f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in trials.glob("c1-*.json") if f.name != "c1-00002.json"}
    assert after == kept  # in particular trial 5 (what the old resume overwrote) is untouched
    assert read_trials(first.path)["c1"][5] == before[5]
    assert validate_tuning(first.path)["methods"]["c1"][0] == 6


def test_a_committed_trial_is_never_overwritten(tmp_path):
    first = tuned(tmp_path, TINY)
    record = {k: v for k, v in read_trials(first.path)["c1"][1].items() if k not in ("tuning", "search", "checksum")}
    tuning = load_tuning(tiny_file(tmp_path, TINY))
    from ilcforce.tune.runner import _header, trial_check

    store = TuningStore(first.path, _header(tuning), {"trials": 2}, check=trial_check(tuning.definition()))
    try:
        with pytest.raises(TuningStoreError, match="already stored; refusing to overwrite it"):
            store.commit(record)
        with pytest.raises(TuningStoreError, match="another `ilcforce tune` is writing"):
            TuningStore(first.path, _header(tuning), {"trials": 2})
        # the folder is the lock: no lock file to delete, in it or beside it
        assert not [p for p in [*first.path.rglob("*"), *first.path.parent.iterdir()] if "lock" in p.name]
    finally:
        store.close()


def test_overwrite_never_follows_a_symlinked_trials_folder(tmp_path):
    one, other = tuned(tmp_path, TINY, results="one"), tuned(tmp_path, TINY, results="two")
    shutil.rmtree(one.path / "trials")
    (one.path / "trials").symlink_to(other.path / "trials")
    with pytest.raises(TuningStoreError, match="not a folder of this store"):
        tuned(tmp_path, TINY, results="one", overwrite=True)
    assert len(list((other.path / "trials").glob("*.json"))) == 4


def test_a_killed_writers_temporary_files_are_removed(tmp_path):
    first = tuned(tmp_path, TINY)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    leftovers = [first.path / "trials" / f".c1-00001.json.tmp-{pid}", first.path / f".tuning.json.tmp-{pid}",
                 first.path / "heldout" / f".c1-00000.json.tmp-{pid}"]
    for item in leftovers:
        item.write_text("{")
    tuned(tmp_path, TINY)
    assert not any(item.exists() for item in leftovers)


# ------------------------------------------------------------------------------------------------
# tune -o


def tune_cli(tmp_path, *args, text=TINY):
    """`ilcforce tune` in a process of its own (real cells: a 0.2 s horizon)."""
    return subprocess.run([sys.executable, "-m", "ilcforce", "tune", str(tiny_file(tmp_path, text)), "--results",
                           str(tmp_path / "r"), "--workers", "1", "-q", *map(str, args)], capture_output=True,
                          text=True, timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})


def test_tune_output_is_refused_where_it_would_destroy_something(tmp_path):
    tuning = load_tuning(tiny_file(tmp_path, TINY))
    existing = tmp_path / "mine.toml"
    existing.write_text("# mine\n")
    store = tmp_path / "c3.h5"
    store.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(600))
    os.mkfifo(tmp_path / "fifo.toml")
    (tmp_path / "folder.toml").mkdir()
    tuned(tmp_path, TINY)
    header = tmp_path / "r" / "tuning" / "tiny" / "tuning.json"
    heldout = tmp_path / "r" / "tuning" / "tiny" / "heldout" / "c1-00000.json"
    cases = {existing: "exists; pass --overwrite", store: "is an HDF5 store", tmp_path / "fifo.toml": "is not a regular file",
             tmp_path / "folder.toml": "is a folder", tmp_path / "tiny.toml": "is the tuning file itself",
             header: "is a file of a tuning store", heldout: "is a file of a tuning store",
             tmp_path / "on" / ".toml": "the tuned experiment file must be named <name>.toml"}
    for output, why in cases.items():
        for overwrite in (False, True):
            if overwrite and why.startswith("exists"):
                continue
            with pytest.raises(TuneError, match=f"-o {output}: {why}"):
                run_tuning(tuning, tmp_path / "r", workers=1, cell_function=fake_cell, output=output,
                           overwrite=overwrite)
    assert existing.read_text() == "# mine\n" and store.read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"
    result = tune_cli(tmp_path, "-o", tmp_path / "on" / ".toml")
    assert result.returncode == 2 and result.stderr.startswith(f"error: -o {tmp_path / 'on' / '.toml'}: "), result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    summary = run_tuning(tuning, tmp_path / "r", workers=1, cell_function=fake_cell, output=existing, overwrite=True)
    assert summary.tuned == existing and existing.read_text().startswith("# Written by `ilcforce tune")


FULL_DISK = """
import resource, signal, sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from ilcforce.tune.output import write_output
from ilcforce.tune.spec import TuneError
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
try:
    write_output(Path({output!r}), "x = 1\\n" * 10000, replace=True)
except TuneError as exc:
    print(exc)
"""


def test_a_full_disk_leaves_an_existing_tuned_file_whole(tmp_path):
    output = tmp_path / "fivebar-tuned.toml"
    output.write_text("# the shipped file\n")
    result = subprocess.run([sys.executable, "-c", FULL_DISK.format(tests=str(Path(__file__).parent), output=str(output))],
                            capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert f"-o {output}: cannot write the tuned experiment file" in result.stdout, result.stdout + result.stderr
    assert output.read_text() == "# the shipped file\n"
    assert not list(tmp_path.glob(".*tmp-*"))


# ------------------------------------------------------------------------------------------------
# outputs that say what happened


def cli_lines(tmp_path, text, monkeypatch, capsys, cell=fake_cell, **kwargs) -> tuple[int, list[str], str]:
    """(exit code, stdout lines, stderr) of `ilcforce tune` (tune_command) with the stand-in ``cell``."""
    from ilcforce.cli.tune import tune_command
    from ilcforce.tune import runner

    monkeypatch.setitem(runner.run_tuning.__kwdefaults__, "cell_function", cell)
    code = tune_command(tiny_file(tmp_path, text), results=tmp_path / "r", workers=1, **kwargs)
    out, err = capsys.readouterr()
    return code, out.splitlines(), err


def test_the_outputs_say_what_the_search_did_and_what_ships(tmp_path, monkeypatch, capsys):
    code, lines, err = cli_lines(tmp_path, TRIALS, monkeypatch, capsys)
    assert code == 0, err
    progress = err.splitlines()
    assert len(progress) == 8 and progress[0].startswith("tune tiny: c1 trial 1/4: error "), progress
    assert all(", feasible (front " in line for line in progress), progress
    c1 = next(line for line in lines if line.startswith("tiny: c1: "))
    assert "4 trials (first budget 4, at most 4), converged" in c1 or "NOT converged" in c1, c1
    assert "ships trial 0: held-out e_P" in c1, c1  # only trial 0 is within the cap (H_x grows with k)
    assert any(line.startswith("tiny: 8 trials run, 0 already stored") and "check runs stopped early" in line
               for line in lines), lines
    assert lines[-1].startswith("tiny: tuned experiment file ") and lines[-1].endswith("tuned.toml`)"), lines
    text = (tmp_path / "r" / "tuning" / "tiny" / "tuned.toml").read_text()
    assert "# c1: 4 trials (" in text and "trial 0: e_P " in text and "(held-out medians)" in text
    assert "2 held-out seeds x 9 iterations" in text and "1 check seeds run 9 iterations" in text
    code, lines, err = cli_lines(tmp_path, TRIALS, monkeypatch, capsys, quiet=True)
    assert code == 0 and err == "" and not any("trials run" in line for line in lines)


def test_a_method_with_no_stable_gains_is_withheld_and_refused_by_name(tmp_path):
    summary = tuned(tmp_path, TINY, cell=failing_cell)
    trials = read_trials(summary.path)["c3"]
    assert all(r["state"] == "failed" and not r["feasible"] for r in trials.values())
    assert summary.chosen["c3"] is None and summary.chosen["c1"] is not None
    text = summary.tuned.read_text()
    assert "# c3: 2 trials (" in text and "no stable gains found under the cap: withheld" in text
    from ilcforce.config_load import load_config

    assert list(load_config(summary.tuned).tuning.withheld) == ["c3"]
    run = CliRunner().invoke(app, ["simulate", "-c", str(summary.tuned), "-m", "c3", "--iters", "1",
                                   "--out", str(tmp_path / "sim.h5")])
    assert run.exit_code == 2, run.output
    assert len(run.output.strip().splitlines()) == 1 and "c3 has no gains in this tuned experiment" in run.output, \
        run.output
    assert "Traceback" not in run.output
    ok = CliRunner().invoke(app, ["simulate", "-c", str(summary.tuned), "-m", "c1", "--iters", "1", "--set",
                                  "reference.duration=0.2", "--out", str(tmp_path / "sim.h5")])
    assert ok.exit_code == 0, ok.output


def late_failing_cell(config, method, keep_store=None, stop=None):
    """Every method diverges at iteration 5: the scored runs (3 iterations) complete, every check and
    held-out run (9) diverges; nothing is stable."""
    result = fake_cell(config, method, keep_store, stop)
    for row in result["rows"][5:]:
        row["status"] = "diverged"
    return result


def test_nothing_stable_writes_no_tuned_file_and_exits_1_with_one_line(tmp_path, monkeypatch, capsys):
    stale = tmp_path / "r" / "tuning" / "tiny" / "tuned.toml"
    code, lines, err = cli_lines(tmp_path, TINY, monkeypatch, capsys, cell=late_failing_cell, quiet=True,
                                 output=tmp_path / "out.toml")
    assert code == 1 and err.count("\n") == 1 and "no method has stable gains under the cap" in err, err
    assert not (tmp_path / "out.toml").exists() and not stale.exists()
    trials = read_trials(tmp_path / "r" / "tuning" / "tiny")
    assert all(r["state"] == "complete" and not r["feasible"] for t in trials.values() for r in t.values())
    assert all("check seed 10: diverged at iteration 5" in r["message"] for t in trials.values() for r in t.values())
    assert any("no stable gains found under the cap" in line for line in lines)


def test_a_cap_reference_that_fails_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    def c1_fails(config, method, keep_store=None, stop=None):
        result = fake_cell(config, method, keep_store, stop)
        if method == "c1":
            result["rows"][0]["status"] = "diverged"
        return result

    code, _lines, err = cli_lines(tmp_path, TINY, monkeypatch, capsys, cell=c1_fails, quiet=True)
    assert code == 2 and err.count("\n") == 1 and "the cap's reference c1 did not complete" in err, err


@pytest.mark.parametrize("spec, message", [
    ('q_order = { low = 0.5, high = 4.0, log = true }', "low >= 1"),
    ('q_order = { low = 1.5, high = 3.7 }', "needs whole numbers"),
])
def test_integer_gain_ranges_are_checked(tmp_path, spec, message):
    text = TINY.replace('methods = ["c1", "c3"]', 'methods = ["c1", "pd-ilc"]')
    text = text[:text.index("[tune.gains.c3]")] + f"[tune.gains.pd-ilc]\n{spec}\n"
    with pytest.raises(TuneError, match=message):
        load_tuning(tiny_file(tmp_path, text))


def test_tune_help_shows_the_tune_table():
    result = CliRunner().invoke(app, ["tune", "--help"], env={"COLUMNS": "200"})
    assert "[tune]" in result.output, result.output


def test_sigterm_ends_tune_with_one_line(tmp_path):
    text = budget(base=50)
    process = subprocess.Popen([sys.executable, "-m", "ilcforce", "tune", str(tiny_file(tmp_path, text)), "--results",
                                str(tmp_path / "r"), "--workers", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    trials = tmp_path / "r" / "tuning" / "tiny" / "trials"
    deadline = time.monotonic() + 240
    while not (trials.is_dir() and list(trials.glob("*.json"))):
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    _out, err = process.communicate(timeout=120)
    stops = [line for line in err.splitlines() if "SIGTERM" in line or "interrupted" in line]
    assert process.returncode == 143 and len(stops) == 1 and stops[0].startswith("terminated (SIGTERM): "), err


# ------------------------------------------------------------------------------------------------
# the report


def test_report_on_a_tuning_only_folder_and_renamed_copies(tmp_path):
    first = tuned(tmp_path, TINY)
    shutil.copytree(first.path, first.path.with_name("tiny-copy"))
    result = CliRunner().invoke(app, ["report", "--results", str(tmp_path / "r"), "--out", str(tmp_path / "report"),
                                      "-q"])
    assert result.exit_code == 0, result.output
    for name in ("tiny", "tiny-copy"):
        assert (tmp_path / "report" / "tuning" / name / "index.md").is_file()
    index = (tmp_path / "report" / "index.md").read_text()
    assert index.count("(tuning/tiny/index.md)") == 1 and index.count("(tuning/tiny-copy/index.md)") == 1


# ------------------------------------------------------------------------------------------------
# the writers' lock of the file stores: a deleted lock file lets a second writer in, and the first
# stops at its next commit instead of writing beside it


def test_a_run_writer_whose_lock_file_was_deleted_stops_before_its_next_commit(tmp_path):
    from storekit import make_record, writer

    from ilcforce.store import StoreLockedError
    from ilcforce.store.filecheck import writers_lock

    path = tmp_path / "c3.h5"
    with writer(path) as first:
        first.append(make_record(0))
        writers_lock(path).unlink()
        with pytest.raises(StoreLockedError, match="lock file was deleted or replaced"):
            first.append(make_record(1))


def test_a_study_driver_whose_lock_file_was_deleted_stops_before_its_next_commit(tmp_path):
    from test_study import small_study

    from ilcforce.store.filecheck import writers_lock
    from ilcforce.store.study import StudyStore, StudyStoreError
    from ilcforce.study.runner import _header

    study = small_study()
    first = StudyStore(tmp_path / "s.h5", header=_header(study), session={"id": "a"})
    try:
        writers_lock(tmp_path / "s.h5").unlink()
        second = StudyStore(tmp_path / "s.h5", header=_header(study), session={"id": "b"})  # let in
        second.close()
        with pytest.raises(StudyStoreError, match="lock file was deleted or replaced"):
            first.commit({"setting": 0, "seed": 0, "method": "c1", "state": "failed", "attempts": 1,
                          "message": "x", "elapsed": 0.1, "worker": "w", "rows": []}, now=0.0)
    finally:
        first.close()


def test_renamed_copies_of_a_study_store_get_their_own_report_pages(tmp_path):
    from test_study import small_study

    from ilcforce.report.build import write_report
    from ilcforce.study import run_study

    first = run_study(small_study(seeds="0-0", methods=("c1",)), tmp_path, workers=1).path
    shutil.copy(first, first.with_name("tiny-copy.h5"))
    summary = write_report(tmp_path, tmp_path / "report", jobs=1)
    for name in ("tiny", "tiny-copy"):
        assert (tmp_path / "report" / "studies" / name / "report.md").is_file(), summary.warnings
        assert (tmp_path / "report" / "studies" / name / "findings.md").is_file(), summary.warnings
    index = (tmp_path / "report" / "index.md").read_text()
    for name in ("tiny", "tiny-copy"):
        assert index.count(f"(studies/{name}/report.md)") == 1, index


def test_a_method_the_tuning_did_not_search_is_left_out_of_studies_and_refused_by_name(tmp_path):
    """A method registered after a tuning ran has no tuned gains in its tuned file ([tuning] methods lists what
    the tuning searched): a study of that file leaves it out of its default methods and refuses it by name, and
    simulate refuses it in one line; the tuning's own methods run. The shipped fivebar-tune searched no-ilc too
    (since it was rerun), so its tuned file is copied with no-ilc left out of [tuning] methods, as the file read
    before that rerun."""
    from ilcforce.config_load import load_config
    from ilcforce.study.spec import StudyError, load_study

    shipped = Path("experiments/fivebar-tuned.toml").read_text(encoding="utf-8")
    searched = '"c2-robust", "c3-robust", "no-ilc"]'
    assert searched in shipped and "no-ilc" in load_config("experiments/fivebar-tuned.toml").tuning.methods
    older = tmp_path / "older-tuned.toml"
    older.write_text(shipped.replace(searched, '"c2-robust", "c3-robust"]'), encoding="utf-8")
    config = load_config(older)
    assert "no-ilc" not in config.tuning.methods and "c1" in config.tuning.methods
    assert "was not tuned by fivebar-tune" in config.tuning.refusal("no-ilc")
    assert config.tuning.refusal("c1") is None and "withheld" in config.tuning.refusal("c2")
    default = tmp_path / "default.toml"
    default.write_text(f'[study]\nname = "default"\nexperiment = "{older}"\nseeds = "0-1"\n')
    study = load_study(default)
    assert "no-ilc" not in study.methods and "c2" not in study.methods and "c1" in study.methods
    named = tmp_path / "named.toml"
    named.write_text(f'[study]\nname = "named"\nexperiment = "{older}"\nmethods = ["c1", "no-ilc"]\nseeds = "0-1"\n')
    with pytest.raises(StudyError, match="no-ilc was not tuned by fivebar-tune"):
        load_study(named)
    run = CliRunner().invoke(app, ["simulate", "-c", str(older), "-m", "no-ilc", "--iters", "1",
                                   "--out", str(tmp_path / "sim.h5")])
    assert run.exit_code == 2 and len(run.output.strip().splitlines()) == 1 and "was not tuned" in run.output, run.output
    assert not (tmp_path / "sim.h5").exists()
