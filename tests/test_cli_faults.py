"""Faults at the command line, and first-class variants: messages
are shown literally, one line, unwrapped, in any locale; the same-run policy decides what is
stale; --set runs get a results folder of their own."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcforce import samerun, store
from ilcforce.cli.main import app

SHORT = ["--set", "reference.duration=0.2"]
VARIANT = "paper--reference.duration=0.2"


@pytest.fixture
def runner():
    return CliRunner()


# -- fault 4: no markup in messages ------------------------------------------------------------------


def test_bad_section_name_is_shown_literally(runner):
    result = runner.invoke(app, ["simulate", "--set", "plnat.m3=1"])
    assert result.exit_code == 2
    assert "unknown section [plnat] (did you mean 'plant'?)" in result.output, result.output


def test_path_with_markup_is_shown_literally(runner, tmp_path: Path):
    weird = tmp_path / "a[/bold]b[red].h5"
    result = runner.invoke(app, ["validate", str(weird)])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert str(weird) in result.output, result.output


# -- fault 13: unwrapped when piped, any locale; compare --overwrite reruns only what differs ---------


def test_validate_line_is_not_wrapped_when_piped(tmp_path: Path):
    deep = tmp_path / ("a-rather-long-folder-name-" * 4) / "c1.h5"
    made = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-m", "c1", "-n", "1", "--out", str(deep),
                           *SHORT], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    result = subprocess.run([sys.executable, "-m", "ilcforce", "validate", str(deep)], capture_output=True,
                            text=True, timeout=300, env={**os.environ, "COLUMNS": "80"})
    assert result.returncode == 0, result.stderr
    assert result.stdout.count("\n") == 1 and str(deep) in result.stdout and len(result.stdout) > 80


def test_ascii_locale_with_a_non_ascii_path(tmp_path: Path):
    """Under an ASCII locale the file name arrives with surrogate escapes: it used to end in a
    UnicodeEncodeError traceback writing the store's provenance."""
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONIOENCODING": "ascii", "PYTHONUTF8": "0"}
    out = tmp_path / "r\u00e9sultat.h5"
    result = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-m", "c3", "-n", "1", "--out", str(out),
                             *SHORT], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and "complete" in result.stdout
    store.validate(out)


def test_compare_overwrite_keeps_identical_results(runner, tmp_path: Path):
    args = ["compare", "--methods", "c1", "-n", "1", "--results", str(tmp_path), *SHORT]
    assert runner.invoke(app, args).exit_code == 0
    path = tmp_path / VARIANT / "c1.h5"
    before = (path.stat().st_ino, path.stat().st_mtime_ns, path.read_bytes())
    assert runner.invoke(app, [*args, "--overwrite"]).exit_code == 0
    assert (path.stat().st_ino, path.stat().st_mtime_ns, path.read_bytes()) == before, "identical result was rerun"


# -- fault 8 and variants: one same-run policy --------------------------------------------------------


def test_resume_refuses_an_integer_change_that_equals_the_iteration_change(runner, tmp_path: Path):
    """substeps 2 -> 3 with --iters 2 -> 3 used to be accepted (the old check tolerated any int that
    changed from the old iteration count to the new one)."""
    out = tmp_path / "c1.h5"
    first = runner.invoke(app, ["simulate", "-m", "c1", "-n", "2", "--out", str(out), *SHORT,
                                "--set", "simulation.substeps=2"])
    assert first.exit_code == 0, first.output
    result = runner.invoke(app, ["simulate", "-m", "c1", "-n", "3", "--out", str(out), "--resume", *SHORT,
                                 "--set", "simulation.substeps=3"])
    assert result.exit_code == 2, result.output
    assert "simulation.substeps" in result.output and "stored 2, new 3" in result.output, result.output
    assert store.iterations(out) == [0, 1]


def test_a_set_run_writes_to_a_folder_of_its_own(runner, tmp_path: Path):
    canonical = ["simulate", "-m", "c1", "-n", "1", "--results", str(tmp_path), *SHORT]
    assert runner.invoke(app, canonical).exit_code == 0
    variant = runner.invoke(app, [*canonical, "--set", "c1.alpha=0.2"])
    assert variant.exit_code == 0, variant.output
    folders = sorted(p.name for p in tmp_path.iterdir())
    assert folders == sorted([VARIANT, samerun.variant_folder("paper", {"reference.duration": 0.2, "c1.alpha": 0.2})])
    assert len(folders) == 2


def test_changing_a_c3_gain_does_not_make_the_c1_store_stale(runner, tmp_path: Path):
    out_c1 = tmp_path / "c1.h5"
    assert runner.invoke(app, ["simulate", "-m", "c1", "-n", "1", "--out", str(out_c1), *SHORT]).exit_code == 0
    provenance = store.read_provenance(out_c1)
    stored = samerun.stored_config(provenance)
    changed = json.loads(json.dumps(stored))
    changed["c3"]["eta"] = 2.0
    assert samerun.differences(stored, changed, "c1") == []
    assert samerun.differences(stored, changed, "c3") == ["c3.eta"]
    changed["simulation"]["substeps"] = 4  # a common section matters to every method
    assert samerun.differences(stored, changed, "c1") == ["simulation.substeps"]


def test_compare_refusal_names_the_keys_that_differ(runner, tmp_path: Path):
    base = ["compare", "--methods", "c1", "-n", "1", "--results", str(tmp_path), *SHORT]
    assert runner.invoke(app, base).exit_code == 0
    # the same folder with a changed common value: only reachable through a config file named "paper"
    toml = tmp_path / "paper-changed.toml"
    toml.write_text('[experiment]\nname = "paper"\n[wall]\nstiffness = 1100.0\n', encoding="utf-8")
    result = runner.invoke(app, [*base, "-c", str(toml)])
    assert result.exit_code == 2, result.output
    assert "wall.stiffness (stored 1000.0, new 1100.0)" in result.output, result.output


@pytest.mark.parametrize("overrides", [{"c3.eta": 2}, {"simulation.sample_time": 2.5e-4, "c3.eta": 2},
                                       {"experiment.name": "x", "plant.model": "serial 2R/x"}])
def test_variant_folder_is_deterministic_and_safe(overrides):
    name = samerun.variant_folder("paper", overrides)
    assert name == samerun.variant_folder("paper", dict(reversed(list(overrides.items()))))
    assert "/" not in name and not name.startswith(".") and len(name) <= 120
    assert all(c.isalnum() or c in "._=,+-" for c in name)


def test_variant_folders_of_different_overrides_differ():
    a = samerun.variant_folder("paper", {"plant.model": "a/b"})
    b = samerun.variant_folder("paper", {"plant.model": "a_b"})
    long_a = samerun.variant_folder("paper", {f"c3.k{i}": i for i in range(40)})
    long_b = samerun.variant_folder("paper", {f"c3.k{i}": i + (i == 39) for i in range(40)})
    assert a != b and long_a != long_b and len(long_a) <= 120


@pytest.mark.parametrize("args, expected", [
    (["compare", "--resume"], "error: No such option: --resume"),
    (["simulate", "--iters", "abc"], "error: Invalid value for '--iters'"),
    (["nosuch"], "error: No such command 'nosuch'."),
    (["study"], "error: give a study file, or a study by its options"),
    (["simulate", "--method"], "error: Option '--method' requires an argument."),
])
def test_usage_errors_of_the_entry_point_are_one_line(args, expected):
    """Typer drew usage errors as a framed box of four or more lines; the entry point says them in
    one line, exit 2, and names the help to read."""
    done = subprocess.run([sys.executable, "-m", "ilcforce", *args], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(expected), done.stderr
    assert done.stdout == ""


def test_no_command_prints_the_help_and_nothing_more():
    done = subprocess.run([sys.executable, "-m", "ilcforce"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "Usage: " in done.stdout + done.stderr and "error:" not in done.stdout + done.stderr


def test_one_value_written_three_ways_is_one_variant():
    """``--set c3.eta=2``, ``=2.0`` and ``=2e0`` are the same configuration but made three results
    folders (the first with the folder name of the text "2", the others "2.0"); they are one now."""
    assert {samerun.variant_folder("paper", {"c3.eta": v}) for v in (2, 2.0, 2e0)} == {"paper--c3.eta=2"}
    assert samerun.variant_folder("paper", {"c3.eta": 2.5}) == "paper--c3.eta=2.5"
    assert samerun.variant_folder("paper", {"wall.stiffness": 1e20}) == "paper--wall.stiffness=1e+20"


# -- found by attacking the CLI's fault handling ---------------------------------------------------


def _entry(*args: str, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ilcforce", *args], capture_output=True, text=True, timeout=120,
                          **kwargs)


def test_a_narrow_table_in_an_ascii_locale_is_whole_and_encodable(tmp_path: Path):
    """rich's Table cut narrow cells with '…', which an ASCII or Latin-1 stdout cannot encode:
    UnicodeEncodeError and exit 1 after the run was stored. Off a terminal a table is now printed
    at its natural width (no cell cut), in an ASCII box where the encoding needs one."""
    for encoding in ("ascii", "latin-1"):
        done = _entry("simulate", "--iters", "1", *SHORT, "--out", str(tmp_path / encoding / "c3.h5"),
                      env={**os.environ, "COLUMNS": "40", "PYTHONIOENCODING": encoding})
        assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
        assert "loop fallbacks" in done.stdout and "\u2026" not in done.stdout and "+--" in done.stdout


def test_a_closed_stdout_is_not_a_traceback(tmp_path: Path):
    out = tmp_path / "c3.h5"
    done = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "--iters", "1", *SHORT, "--out", str(out)],
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=120,
                          preexec_fn=lambda: os.close(1))
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr and store.read_provenance(out)["run_state"] == "complete"


@pytest.mark.parametrize("out", [".", "..", ""])
def test_an_out_path_without_a_file_name_is_one_line(out, tmp_path: Path):
    done = _entry("simulate", "--iters", "1", *SHORT, "--out", out, cwd=tmp_path / ".." if out == ".." else tmp_path)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "not a file name for a store" in done.stderr


def test_compare_refuses_another_methods_store_under_a_methods_name(runner, tmp_path: Path):
    """A c1 store copied to c3.h5 was shown as c3 by compare, without a word."""
    folder = tmp_path / VARIANT
    assert runner.invoke(app, ["simulate", "-m", "c1", "--iters", "1", *SHORT, "--results", str(tmp_path)]).exit_code == 0
    (folder / "c3.h5").write_bytes((folder / "c1.h5").read_bytes())
    result = runner.invoke(app, ["compare", "--methods", "c1,c3", "--iters", "1", *SHORT, "--results", str(tmp_path)])
    assert result.exit_code == 2 and "holds a c1 run, not c3" in result.output
    result = runner.invoke(app, ["compare", "--methods", "c1,c3", "--iters", "1", *SHORT, "--results", str(tmp_path),
                                 "--overwrite"])
    assert result.exit_code == 0, result.output
    assert store.read_provenance(folder / "c3.h5")["method"] == "c3"


def test_out_of_memory_is_one_line(runner, tmp_path: Path, monkeypatch):
    from ilcforce import experiment

    def no_memory(*args, **kwargs):
        raise MemoryError("Unable to allocate 15.3 MiB for an array with shape (1000001, 2) and data type float64")

    monkeypatch.setattr(experiment, "run_method", no_memory)
    result = runner.invoke(app, ["simulate", "--iters", "1", *SHORT, "--out", str(tmp_path / "c3.h5")])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        "error: out of memory: Unable to allocate 15.3 MiB for an array with shape (1000001, 2) and data type "
        "float64 (every finished iteration is stored)"]


def test_a_users_empty_openblas_setting_means_one_thread():
    code = ("import os, sys; sys.argv = ['ilcforce', 'version']; from ilcforce.cli import entry; entry.one_blas_thread(); "
            "print(os.environ['OPENBLAS_NUM_THREADS'])")
    for given, expected in (("", "1"), ("3", "3"), (None, "1")):
        env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
        if given is not None:
            env["OPENBLAS_NUM_THREADS"] = given
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env)
        assert done.stdout.strip() == expected, (given, done.stdout, done.stderr)
