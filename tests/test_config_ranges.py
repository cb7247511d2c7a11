"""Every field has a stated valid range, checked
before any work, including the memory a run would need. Each case was a traceback (some after an
iteration had been simulated) before the ranges existed."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.config import ConfigError
from ilcforce.config_load import config_from_dict, default_config, load_config
from ilcforce.config_ranges import RANGES, range_of

HUGE = "99999999999999999999"
CASES = [
    (["--seed", HUGE], "experiment.seed must be in [0, 9223372036854775807], got"),  # not 9.22337e+18
    (["--iters", HUGE], "experiment.iterations must be in [1, 100000]"),
    (["--set", "wall.stiffness=" + "1" * 400], "wall.stiffness must be finite, got an integer with 400 digits"),
    (["--set", "reference.duration=1e308"], "reference.duration must be in (0, 600]"),
    (["--set", "reference.duration=1e4"], "reference.duration must be in (0, 600]"),
    (["--set", "simulation.sample_time=1e-9"], "simulation.sample_time must be in [1e-06, 0.1]"),
    (["--set", "simulation.substeps=1e30"], "simulation.substeps must be an integer"),
    (["--set", "simulation.substeps=100000"], "integrator steps"),
    (["--set", "plnat.m3=1"], "unknown section [plnat] (did you mean 'plant'?)"),
]


@pytest.mark.parametrize("args, expected", CASES, ids=[c[1][:40] for c in CASES])
def test_out_of_range_input_is_one_line_before_any_work(tmp_path: Path, args, expected):
    result = CliRunner().invoke(app, ["simulate", "--results", str(tmp_path), *args])
    assert result.exit_code == 2, result.output
    assert expected in result.output, result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir()), "nothing may be written for a refused configuration"


def test_memory_a_run_would_need_is_checked(monkeypatch: pytest.MonkeyPatch):
    # 1e-6 s over 600 s is a valid sample time and duration, but 6e8 samples of ~800 bytes is not
    with pytest.raises(ConfigError, match="GiB of memory"):
        config_from_dict({"reference": {"duration": 600.0}, "simulation": {"sample_time": 1e-6}})


def test_nul_and_control_characters_in_names_are_refused(tmp_path: Path):
    toml = tmp_path / "nul.toml"
    toml.write_text('[experiment]\nname = "a\\u0000b"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="printable"):
        load_config(toml)


@pytest.mark.parametrize("kind", ["directory", "fifo", "device"])
def test_config_that_is_not_a_file_is_named_for_what_it_is(tmp_path: Path, kind: str):
    if kind == "directory":
        target, expected = tmp_path, "is a directory"
    elif kind == "fifo":
        target = tmp_path / "pipe.toml"
        os.mkfifo(target)
        expected = "not a regular file"
    else:
        target, expected = Path("/dev/zero"), "not a regular file"
    start = time.monotonic()
    with pytest.raises(ConfigError, match=expected):
        load_config(target)
    assert time.monotonic() - start < 5  # a FIFO is never opened (that would block)


def test_every_field_of_the_default_config_is_inside_its_range():
    """The ranges are stated for every field (a default per type); the defaults lie inside them."""
    def walk(obj, prefix):
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            path = f"{prefix}.{f.name}"
            if dataclasses.is_dataclass(value):
                yield from walk(value, path)
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                yield path, value
            elif isinstance(value, tuple):
                for item in value:
                    if isinstance(item, (int, float)):
                        yield path, item

    config = default_config()
    checked = 0
    for section in ("experiment", "plant", "wall", "reference", "simulation", "noise", "surface"):
        for path, value in walk(getattr(config, section), section):
            assert range_of(path, type(value)).contains(value), (path, value)
            checked += 1
    for method, gains in config.gains.items():
        for path, value in walk(gains, method):
            assert range_of(path, type(value)).contains(value), (path, value)
            checked += 1
    assert checked > 40
    assert all(key.count(".") >= 1 for key in RANGES)


def test_no_runtime_warning_leaks_for_a_long_reference():
    result = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-c",
                             "from ilcforce.config import ConfigError\nfrom ilcforce.config_load import load_config\n"
                             "try:\n    load_config(None, {'reference.duration': 1e4})\n"
                             "except ConfigError as e:\n    print(e)\n"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "RuntimeWarning" not in result.stderr, result.stderr
    assert "reference.duration must be in" in result.stdout


@pytest.mark.parametrize("toml, expected", [
    ('[experiment]\ndescription = 1979-05-27\n', "experiment.description must be a string, got a date (1979-05-27)"),
    ('[experiment]\nname = 1979-05-27T07:32:00Z\n', "got a date-time (1979-05-27T07:32:00+00:00)"),
    ('[wall]\nstiffness = 07:32:00\n', "wall.stiffness must be a number, got a time (07:32:00)"),
    ('[plant]\nperturbation = [1979-05-27]\n', "[plant.perturbation] must be a table, got [a date (1979-05-27)]"),
    ('[study]\nname = "s"\nmethods = ["c3"]\nseeds = 2020-01-01\n', "study.seeds must be a range"),
])
def test_a_toml_date_or_time_is_shown_as_written(tmp_path: Path, toml: str, expected: str):
    """TOML dates and times were echoed as Python's repr (``datetime.date(1979, 5, 27)``), which the
    user never wrote; they are now named and shown as in the file."""
    path = tmp_path / "dated.toml"
    path.write_text(toml, encoding="utf-8")
    command = ["study", str(path)] if toml.startswith("[study]") else ["config", "-c", str(path)]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 2, result.output
    assert expected in result.output and "datetime" not in result.output, result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1
