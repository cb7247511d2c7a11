"""The README's shell examples run as written, in order, in a scratch folder holding only a copy of
experiments/: the usage block, then the study block with the study file the README shows (saved as
it says). The 100-seed study line is left to `make reproduce`, which runs it."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _block(marker: str, language: str) -> str:
    after = README.split(f"<!-- {marker}: run by tests/test_readme.py -->", 1)
    assert len(after) == 2, f"README has no block marked {marker}"
    match = re.match(rf"\s*```{language}\n(.*?)```", after[1], re.S)
    assert match, f"the block marked {marker} is not a {language} block"
    return match.group(1)


def _commands(block: str) -> list[str]:
    """The block's commands, comments dropped, the virtual environment's programs made this one's."""
    commands = []
    for line in block.strip().splitlines():
        command = re.split(r"\s{2,}#", line)[0].strip()
        command = re.sub(r"^\.venv/bin/ilcforce\b", f"{sys.executable} -m ilcforce", command)
        command = re.sub(r"^\.venv/bin/python\b", sys.executable, command)
        commands.append(command)
    return commands


def _run_all(commands: list[str], cwd: Path) -> None:
    for command in commands:
        done = subprocess.run(command, shell=True, cwd=cwd, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"{command}\n{done.stderr}"
        assert "Traceback" not in done.stderr, f"{command}\n{done.stderr}"


def _docs_api_snippet() -> str:
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    match = re.search(r"```python\n(.*?)```", text, re.S)
    assert match, "docs/api.md has no python example"
    return match.group(1)


def test_the_usage_examples_run_as_written_in_order(tmp_path):
    """The README's usage block, then docs/api.md's example twice in the same folder (examples run
    in any order and again): everything they write stays under results/mine/."""
    shutil.copytree(ROOT / "experiments", tmp_path / "experiments")
    commands = _commands(_block("readme-usage", "sh"))
    assert any(" simulate " in c for c in commands) and any(" report " in c for c in commands)
    _run_all(commands, tmp_path)
    assert (tmp_path / "results" / "mine" / "report" / "index.md").is_file()
    assert (tmp_path / "results" / "mine" / "report" / "index.html").is_file()
    (tmp_path / "api_example.py").write_text(_docs_api_snippet(), encoding="utf-8")
    _run_all([f"{sys.executable} api_example.py"] * 2, tmp_path)
    assert (tmp_path / "results" / "mine" / "api-c3-eta2.h5").is_file()
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == ["mine"]  # your own runs stay there


def test_the_study_example_runs_as_written(tmp_path):
    shutil.copytree(ROOT / "experiments", tmp_path / "experiments")
    (tmp_path / "my-sweep.toml").write_text(_block("readme-study-file", "toml"), encoding="utf-8")
    commands = [c for c in _commands(_block("readme-study", "sh")) if "paper-mc" not in c]
    assert len(commands) == 2
    _run_all(commands, tmp_path)
    table = (tmp_path / "results" / "mine" / "my-sweep.csv").read_text(encoding="utf-8").splitlines()
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == ["mine"], "a study example wrote outside results/mine"
    assert len(table) > 1 + 2 * 2 * 2  # a header, then rows for 2 methods x 2 seeds x 2 sample times
