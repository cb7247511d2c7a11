"""Experiment and study files that cannot be taken (ilcforce.tomlfile): one line, exit 2, at once.

Found by an attack on the CLI: a 5000-digit integer (Python's int-string limit) and nesting deeper
than the recursion limit escaped tomllib as ValueError / RecursionError and printed tracebacks; a
huge file was read whole (3 GB: 21 s and 6 GB of memory) before being refused.
"""

from __future__ import annotations

import os

import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.config import ConfigError
from ilcforce.config_load import load_config, parse_override
from ilcforce.tomlfile import MAX_TOML_BYTES

BIG_INT = "1" * 5000
DEEP = "[" * 5000 + "]" * 5000
#: A table header 500 tables deep: tomllib builds it without recursion, and every recursive walk of
#: the result then raised RecursionError (found by an attack: a traceback; 200 deep got one line).
DEEP_TABLES = ".".join(["a"] * 500)


def _one_line_exit_2(result, expected: str) -> None:
    text = result.output.strip()
    assert result.exit_code == 2, f"exit {result.exit_code}: {text}"
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert expected in text, text
    assert len(text.splitlines()) == 1, f"expected one line, got:\n{text}"


def _write(tmp_path, kind: str, body: str):
    path = tmp_path / f"{kind}.toml"
    path.write_text(body)
    return path


@pytest.mark.parametrize("body, expected", [
    (f"[experiment]\nseed = {BIG_INT}\n", "is not valid TOML: Exceeds the limit"),
    (f"[experiment]\nseed = {DEEP}\n", "is not valid TOML: arrays or tables nested too deeply"),
    (f"[experiment]\nseed = 1\n[{DEEP_TABLES}]\nx = 1\n", "is not valid TOML: tables or arrays nested more than 32 deep"),
])
def test_experiment_file_tomllib_cannot_take_is_one_line(tmp_path, body, expected):
    path = _write(tmp_path, "experiment", body)
    args = ["simulate", "-m", "c1", "-n", "1", "-c", str(path), "--out", str(tmp_path / "x.h5")]
    _one_line_exit_2(CliRunner().invoke(app, args), expected)
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("body", [f'[study]\nname = "x"\nseeds = {BIG_INT}\n', f'[study]\nname = "x"\nseeds = {DEEP}\n',
                                  f'[study]\nname = "x"\n[{DEEP_TABLES}]\nx = 1\n'])
def test_study_file_tomllib_cannot_take_is_one_line(tmp_path, body):
    path = _write(tmp_path, "study", body)
    result = CliRunner().invoke(app, ["study", str(path), "--workers", "1", "--results", str(tmp_path / "r")])
    _one_line_exit_2(result, f"study file {path} is not valid TOML")


def test_a_file_over_the_size_limit_is_refused_without_reading_it(tmp_path):
    path = tmp_path / "huge.toml"
    with path.open("wb") as handle:  # sparse: costs no disk
        handle.truncate(MAX_TOML_BYTES + 1)
    with pytest.raises(ConfigError, match="is larger than 4 MB"):
        load_config(path)
    result = CliRunner().invoke(app, ["study", str(path), "--workers", "1", "--results", str(tmp_path / "r")])
    _one_line_exit_2(result, "is larger than 4 MB")


def test_a_dangling_or_looping_symlink_is_named_as_such(tmp_path):
    loop = tmp_path / "loop.toml"
    os.symlink(loop, loop)
    dangling = tmp_path / "dangling.toml"
    os.symlink(tmp_path / "nowhere.toml", dangling)
    for path in (loop, dangling):
        with pytest.raises(ConfigError, match="symbolic link that leads nowhere"):
            load_config(path)


@pytest.mark.parametrize("raw", [BIG_INT, DEEP])
def test_set_value_tomllib_cannot_take_is_a_string_then_refused_by_its_field(raw):
    key, value = parse_override(f"experiment.seed={raw}")
    assert (key, value) == ("experiment.seed", raw)
    with pytest.raises(ConfigError, match="experiment.seed"):
        load_config(None, {key: value})


@pytest.mark.parametrize("kind", ["experiment", "study"])
def test_a_byte_order_mark_is_named(tmp_path, kind):
    """A file saved "UTF-8 with BOM" (Windows editors): tomllib said only 'Invalid statement (line 1,
    col 1)'; the line now names the byte-order mark."""
    path = tmp_path / f"{kind}.toml"
    body = '[study]\nname = "x"\nseeds = "0-1"\n' if kind == "study" else "[experiment]\nseed = 1\n"
    path.write_bytes(b"\xef\xbb\xbf" + body.encode())
    args = (["study", str(path), "--workers", "1", "--results", str(tmp_path / "r")] if kind == "study" else
            ["simulate", "-m", "c1", "-n", "1", "-c", str(path), "--out", str(tmp_path / "x.h5")])
    _one_line_exit_2(CliRunner().invoke(app, args), "starts with a UTF-8 byte-order mark (BOM)")
