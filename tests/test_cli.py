"""The command line through typer's CliRunner: happy paths and one clear line for every bad input."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from ilcforce import store
from ilcforce.cli.main import app

SHORT = ["--set", "reference.duration=0.2"]
VARIANT = "paper--reference.duration=0.2"  # --set runs write to a results folder of their own


@pytest.fixture
def runner():
    return CliRunner()


def _one_clear_line(result, expected: str):
    text = result.output.strip()
    assert result.exit_code == 2, f"exit {result.exit_code}: {text}"
    assert "Traceback" not in text and result.exception is None or isinstance(result.exception, SystemExit)
    assert expected in text, text
    assert len(text.splitlines()) == 1, f"expected one line, got:\n{text}"


def test_simulate_writes_a_valid_store(runner, tmp_path):
    out = tmp_path / "c3.h5"
    result = runner.invoke(app, ["simulate", "--method", "c3", "--iters", "2", "--out", str(out), *SHORT])
    assert result.exit_code == 0, result.output
    assert "complete" in result.output
    store.validate(out)
    assert store.iterations(out) == [0, 1]
    prov = store.read_provenance(out)
    assert prov["run_state"] == "complete" and prov["method"] == "c3" and prov["seed"] == 0
    assert prov["command"].startswith("ilcforce simulate --method c3 --iters 2")


def test_default_output_path_and_existing_result(runner, tmp_path):
    args = ["simulate", "-m", "c1", "-n", "1", "--results", str(tmp_path), *SHORT]
    assert runner.invoke(app, args).exit_code == 0
    path = tmp_path / VARIANT / "c1.h5"
    assert path.is_file()
    before = path.read_bytes()
    _one_clear_line(runner.invoke(app, args), "--overwrite replaces it")
    assert path.read_bytes() == before, "an existing result must not be touched without --overwrite"
    assert runner.invoke(app, [*args, "--overwrite"]).exit_code == 0


def test_resume_continues(runner, tmp_path):
    out = tmp_path / "c2.h5"
    assert runner.invoke(app, ["simulate", "-m", "c2", "-n", "2", "--out", str(out), *SHORT]).exit_code == 0
    result = runner.invoke(app, ["simulate", "-m", "c2", "-n", "4", "--out", str(out), "--resume", *SHORT])
    assert result.exit_code == 0, result.output
    assert store.iterations(out) == [0, 1, 2, 3]


def test_diverged_method_is_a_result(runner, tmp_path):
    out = tmp_path / "c2.h5"
    result = runner.invoke(app, ["simulate", "-m", "c2", "-n", "3", "--out", str(out), "--set", "wall.force_sign=paper",
                                 "--set", "reference.duration=0.5"])
    assert result.exit_code == 0, result.output
    assert "diverged" in result.output
    assert store.read_provenance(out)["run_state"] == "diverged"


def test_compare_and_report(runner, tmp_path):
    results = tmp_path / "results"
    result = runner.invoke(app, ["compare", "--methods", "c1,c3", "-n", "2", "--results", str(results), *SHORT])
    assert result.exit_code == 0, result.output
    assert "c1" in result.output and "c3" in result.output
    again = runner.invoke(app, ["compare", "--methods", "c1,c3", "-n", "2", "--results", str(results), *SHORT])
    assert again.exit_code == 0, again.output
    report = runner.invoke(app, ["report", "--results", str(results), "--out", str(tmp_path / "rep")])
    assert report.exit_code == 0, report.output
    assert (tmp_path / "rep" / "index.md").is_file()
    pngs = sorted((tmp_path / "rep").rglob("*.png"))
    assert pngs and not list((tmp_path / "rep").rglob("*.pdf")), "PNG only unless --pdf"
    with_pdf = runner.invoke(app, ["report", "--results", str(results), "--out", str(tmp_path / "pdf"), "--pdf"])
    assert with_pdf.exit_code == 0, with_pdf.output
    # every figure the report draws has its PDF; the long runs' pages are make long's, copied in as committed
    drawn = [p for p in pngs if p.parent != tmp_path / "rep" / "long-run"]
    assert drawn and {p.stem for p in (tmp_path / "pdf").rglob("*.pdf")} == {p.stem for p in drawn}


@pytest.mark.parametrize("args, expected", [
    (["simulate", "--method", "c9"], "unknown method 'c9'"),
    (["simulate", "--iters", "0"], "--iters must be >= 1"),
    (["simulate", "--iters", "-3"], "--iters must be >= 1"),
    (["simulate", "--seed", "-1"], "--seed must be >= 0"),
    (["simulate", "--config", "missing.toml"], "missing.toml does not exist"),
    (["simulate", "--set", "c3.gamm=[1]"], "did you mean 'gamma'"),
    (["simulate", "--set", "simulation.sample_time=3e-4"], "does not divide the horizon"),
    (["simulate", "--set", "reference.x_offset=0.9"], "leaves the reachable workspace"),
    (["simulate", "--set", "c3"], "KEY=VALUE"),
    (["compare", "--methods", "c1,cx"], "unknown method 'cx'"),
    (["validate", "nothing-here.h5"], "nothing-here.h5"),
])
def test_bad_input_one_line(runner, args, expected):
    _one_clear_line(runner.invoke(app, args), expected)


def test_bad_config_files(runner, tmp_path):
    empty = tmp_path / "empty.toml"
    empty.write_text("")
    _one_clear_line(runner.invoke(app, ["simulate", "-c", str(empty)]), "is empty")
    junk = tmp_path / "junk.toml"
    junk.write_text("this is = = not toml")
    _one_clear_line(runner.invoke(app, ["simulate", "-c", str(junk)]), "not valid TOML")
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    _one_clear_line(runner.invoke(app, ["simulate", "-c", str(binary)]), "binary.toml")


def test_unwritable_output(runner, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    _one_clear_line(runner.invoke(app, ["simulate", "-n", "1", "--out", str(blocker / "sub" / "c3.h5"), *SHORT]),
                    str(blocker))


def _foreign(path):
    with h5py.File(path, "w") as f:
        f.attrs["schema"] = "someone.else"
        f["x"] = np.arange(3)


def _newer(tmp_path, runner):
    path = tmp_path / "newer.h5"
    assert runner.invoke(app, ["simulate", "-n", "1", "--out", str(path), *SHORT]).exit_code == 0
    with h5py.File(path, "a") as f:
        f.attrs["schema_version"] = "99.0"
    return path


def test_bad_store_files(runner, tmp_path):
    empty = tmp_path / "empty.h5"
    empty.write_bytes(b"")
    _one_clear_line(runner.invoke(app, ["validate", str(empty)]), "empty.h5")
    foreign = tmp_path / "foreign.h5"
    _foreign(foreign)
    _one_clear_line(runner.invoke(app, ["validate", str(foreign)]), "not an ilcforce store")
    good = tmp_path / "good.h5"
    assert runner.invoke(app, ["simulate", "-n", "1", "--out", str(good), *SHORT]).exit_code == 0
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    _one_clear_line(runner.invoke(app, ["validate", str(truncated)]), "truncated.h5")
    _one_clear_line(runner.invoke(app, ["validate", str(_newer(tmp_path, runner))]), "newer")
    # resuming onto a foreign file refuses and leaves it alone
    before = foreign.read_bytes()
    _one_clear_line(runner.invoke(app, ["simulate", "-n", "1", "--out", str(foreign), "--resume", *SHORT]), "foreign.h5")
    assert foreign.read_bytes() == before


def test_report_skips_bad_files_with_a_warning(runner, tmp_path):
    results = tmp_path / "results"
    assert runner.invoke(app, ["simulate", "-m", "c1", "-n", "1", "--results", str(results), *SHORT]).exit_code == 0
    (results / VARIANT / "c2.h5").write_bytes(b"not hdf5 at all")
    result = runner.invoke(app, ["report", "--results", str(results), "--out", str(tmp_path / "rep")])
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    assert "c2.h5" in result.output
    _one_clear_line(runner.invoke(app, ["report", "--results", str(tmp_path / "nowhere")]), "does not exist")


def test_the_entry_point_exits_at_once_with_the_commands_code_and_its_output(tmp_path):
    """main() ends with os._exit (skipping numba's slow teardown): the exit code and everything written
    to stdout and stderr must still come out, also into a pipe or a file."""
    import subprocess
    import sys

    ok = subprocess.run([sys.executable, "-m", "ilcforce", "version"], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and ok.stdout.startswith("ilcforce "), (ok.returncode, ok.stdout, ok.stderr)
    bad = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "--iters", "0"], capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode == 2 and "--iters must be >= 1" in bad.stderr, (bad.returncode, bad.stderr)
    out = tmp_path / "run" / "c1.h5"
    with open(tmp_path / "stdout.txt", "w") as handle:
        run = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-m", "c1", "-n", "1", "--out", str(out),
                              *SHORT], stdout=handle, stderr=subprocess.PIPE, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "complete" in (tmp_path / "stdout.txt").read_text()  # the table's row, written just before the exit
    store.validate(out)


def test_compare_over_fewer_iterations_than_stored_shows_the_first_ones(runner, tmp_path):
    """`compare --iters 2` reused a store holding more iterations (the first ones are the same run)
    but showed all of them (j19 values under a "2 iterations" title); the table is over the
    iterations asked for, like its title, and names the folder its stores are in."""
    args = ["compare", "--methods", "c1,c3", "--results", str(tmp_path), *SHORT]
    assert runner.invoke(app, [*args, "--iters", "3"]).exit_code == 0
    result = runner.invoke(app, [*args, "--iters", "2"])
    assert result.exit_code == 0, result.output
    words = " ".join(result.output.split())  # the title wraps at the table's width
    assert "(seed 0, 2 iterations) ->" in words and VARIANT in words, result.output
    cells = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:-1]]
             for line in result.output.splitlines() if line.startswith("│")}
    assert cells["iterations"] == ["2", "2"], result.output
    assert cells["position_error_2norm_j0 (m)"] != ["-", "-"], result.output
    assert store.iterations(tmp_path / VARIANT / "c3.h5") == [0, 1, 2]  # the store itself is untouched


def test_an_experiment_file_without_a_name_is_named_after_the_file(runner, tmp_path):
    """Its runs went to the paper's own folder, results/paper/."""
    mine = tmp_path / "mine.toml"
    mine.write_text("[c3]\neta = 2.0\n", encoding="utf-8")
    result = runner.invoke(app, ["simulate", "-m", "c3", "-n", "1", "-c", str(mine), "--results", str(tmp_path), *SHORT])
    assert result.exit_code == 0, result.output
    assert store.iterations(tmp_path / "mine--reference.duration=0.2" / "c3.h5") == [0]
    assert not (tmp_path / "paper--reference.duration=0.2").exists()
    hidden = tmp_path / ".hidden.toml"
    hidden.write_text("[c3]\neta = 2.0\n", encoding="utf-8")
    _one_clear_line(runner.invoke(app, ["config", "-c", str(hidden)]), "set experiment.name")


def test_report_names_a_file_given_as_a_folder(runner, tmp_path):
    """`report --out FILE` printed the raw "File exists" and `report --results FILE` said the file
    "does not exist"; each is named now, and the file is left as it was."""
    (tmp_path / "results").mkdir()
    text = tmp_path / "notes.txt"
    text.write_text("mine\n", encoding="utf-8")
    _one_clear_line(runner.invoke(app, ["report", "--results", str(tmp_path / "results"), "--out", str(text)]),
                    "is a file, not a folder")
    _one_clear_line(runner.invoke(app, ["report", "--results", str(text)]), "is a file, not a folder of stores")
    assert text.read_text(encoding="utf-8") == "mine\n"


def test_validate_skips_the_files_kept_beside_a_store(runner, tmp_path):
    """`ilcforce validate results/paper/*` exited 2 on the writers' lock files beside the stores."""
    out = tmp_path / "c3.h5"
    assert runner.invoke(app, ["simulate", "-m", "c3", "-n", "1", "--out", str(out), *SHORT]).exit_code == 0
    assert (tmp_path / "c3.h5.lock").is_file()
    orphan = tmp_path / "gone.h5.lock"
    orphan.write_text("", encoding="utf-8")
    (tmp_path / "study.h5.journal").mkdir()  # a study's journal folder
    result = runner.invoke(app, ["validate", *map(str, sorted(tmp_path.iterdir()))])
    assert result.exit_code == 0, result.output
    assert f"c3.h5.lock: skipped (the writers' lock file of {out})" in result.output
    assert "gone.h5.lock: skipped (the writers' lock file of" in result.output and "which is not there" in result.output
    assert "study.h5.journal: skipped (the journal of" in result.output
    assert "c3.h5: ok" in result.output
    stray = tmp_path / "notes.lock"  # not beside a store's name: checked, and not a store
    stray.write_text("x", encoding="utf-8")
    assert runner.invoke(app, ["validate", str(stray)]).exit_code == 2


@pytest.mark.parametrize("command", ["simulate", "compare", "config"])
def test_the_number_of_iterations_is_given_once_with_iters(runner, tmp_path, command):
    """`--set experiment.iterations=3` wrote the experiment's own store (the only --set key that made no
    variant), and `--iters 2 --set experiment.iterations=5` ran 2 without a word: both are refused in
    favour of --iters, one line, exit 2, nothing written; so is a seed given both ways."""
    results = tmp_path / "results"
    for args, expected in (
            (["--set", "experiment.iterations=3"], "--set experiment.iterations=3: give the number of iterations "
                                                   "with --iters"),
            (["--iters", "2", "--set", "experiment.iterations=5"], "--set experiment.iterations=5: give the number"),
            (["--seed", "5", "--set", "experiment.seed=3"], "--seed 5 and --set experiment.seed=3 both give the seed")):
        _one_clear_line(runner.invoke(app, [command, *args, *SHORT, *(["--results", str(results)]
                                                                       if command != "config" else [])]), expected)
    assert not results.exists(), "a refused command writes nothing"
    # the one way: --iters, into the experiment's own store (iterations never make a variant)
    if command == "simulate":
        assert runner.invoke(app, [command, "-m", "c1", "--iters", "1", "--results", str(results)]).exit_code == 0
        assert (results / "paper" / "c1.h5").is_file()


def test_study_progress_says_compiling_until_a_cell_finishes_then_an_eta_without_the_compiling(capsys):
    """The first progress line of a study said "ETA 27794 s": its first cell finished after 12 minutes
    of compiling and the ETA took that for the pace. Now: "compiling" while no cell of this run has
    finished, no ETA from the first (it paid for the compiling), then the pace since the first."""
    from ilcforce.cli.study import _StudyProgress
    from ilcforce.study.runner import Progress

    clock = [100.0]
    progress = _StudyProgress("s", quiet=False)
    progress._time = lambda: clock[0]
    with progress:
        steps = [(0.0, 2, ""), (720.0, 3, "c1 seed 0"), (730.0, 4, "c1 seed 1"), (750.0, 5, "c1 seed 2")]
        for at, finished, last in steps:  # 2 of 42 cells stored before; 40 to run
            clock[0] = 100.0 + at
            progress(Progress(total=42, finished=finished, failed=0, to_run=40, last=last))
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "s: 2/42 cells, 0 failed, 0 s, compiling, no cell finished yet", lines
    assert lines[1] == "s: 3/42 cells, 0 failed, 720 s, first cell finished (compiling included), ETA after the next"
    # 10 s for the one cell after the first: 38 cells left take 380 s (not 720 s x 38 = 27360 s)
    assert lines[2] == "s: 4/42 cells, 0 failed, 730 s, ETA 380 s", lines
    assert lines[3] == "s: 5/42 cells, 0 failed, 750 s, ETA 555 s", lines  # 30 s / 2 cells x 37


def _comment_paths(root):
    """(file, path) for every experiments/ path named in a comment of an experiment file or the Makefile."""
    import re

    found = []
    files = sorted((root / "experiments").rglob("*.toml")) + [root / "Makefile"]
    for file in files:
        for line in file.read_text(encoding="utf-8").splitlines():
            comment = line.strip()
            if file.name == "Makefile" and "## " in comment and not comment.startswith("#"):
                comment = comment.split("## ", 1)[1]  # a target's help text
            elif not comment.startswith("#"):
                continue
            found += [(file, p.rstrip(".,:;)")) for p in re.findall(r"experiments/[\w.*/-]*", comment)]
    return found


def test_every_experiments_path_a_comment_names_exists():
    """arm3.toml named experiments/full/arm3-mc.toml, which never existed: a path in a comment of an
    experiment file or the Makefile is a file (or, with *, a pattern matching one) of the repository."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    named = _comment_paths(root)
    assert len(named) > 20, named  # the comments do name paths: the scan reads them
    missing = [(f.relative_to(root).as_posix(), p) for f, p in named
               if not (any(root.glob(p)) if "*" in p else (root / p).exists())]
    assert missing == [], missing


def test_help_points_at_what_an_install_has():
    """`ilcforce --help` pointed at README.md, which a pip install does not have."""
    result = CliRunner().invoke(app, ["--help"])
    assert result.exit_code == 0 and "README" not in result.output
    assert "ilcforce COMMAND --help" in " ".join(result.output.split())
    study = CliRunner().invoke(app, ["study", "--help"])
    assert study.exit_code == 0 and "README" not in study.output and "study.sweep" in study.output
