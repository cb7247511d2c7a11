"""What `pip install .` gives a user: every package, the shipped experiment files (installed as
ilcforce/experiments/, usable by name: `ilcforce simulate -c serial2r`), and a command that runs from
any folder. The wheel is built from a copy of the sources and installed into a fresh venv that
borrows only the third-party dependencies of the test's own environment, so the experiments can
only come from the wheel."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest

from ilcforce.tomlfile import resolve_toml, shipped_folder, shipped_names

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_folder_is_listed_in_pyproject():
    """The packages are listed by hand (the experiments are mapped from the repository's folder):
    a new package folder left off the list would be missing from every pip install."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = {".".join(p.relative_to(ROOT).parts) for p in (ROOT / "ilcforce").rglob("*")
               if p.is_dir() and p.name != "__pycache__" and any(p.glob("*.py"))}
    folders.add("ilcforce")
    assert folders, "no package folder found: the test would pass vacuously"
    assert sorted(folders - listed) == [], "package folders missing from pyproject's [tool.setuptools] packages"


def test_a_shipped_experiment_is_found_by_its_bare_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nowhere near the repository's experiments/
    assert shipped_folder() == ROOT / "experiments"
    assert resolve_toml("serial2r") == ROOT / "experiments" / "serial2r.toml"
    assert resolve_toml("serial2r.toml") == ROOT / "experiments" / "serial2r.toml"
    assert resolve_toml("serial2r-tune") == ROOT / "experiments" / "tuning" / "serial2r-tune.toml"
    assert "paper" in shipped_names() and "serial2r" in shipped_names()
    # a file of the user's own wins over a shipped one of the same name; a path is never looked up
    (tmp_path / "serial2r.toml").write_text("[experiment]\nname = 'mine'\n")
    assert resolve_toml("serial2r.toml") == Path("serial2r.toml")
    assert resolve_toml("sub/serial2r.toml") == Path("sub/serial2r.toml")
    assert resolve_toml("no-such-experiment") == Path("no-such-experiment")


def test_an_unknown_name_lists_the_shipped_ones(tmp_path, monkeypatch):
    from ilcforce.config import ConfigError
    from ilcforce.config_load import load_config

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"serial3r does not exist \(shipped experiments, usable by name: .*serial2r"):
        load_config("serial3r")
    assert load_config("serial2r").plant.model == "serial2r"


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh venv holding the wheel built from this checkout; its bin folder."""
    work = tmp_path_factory.mktemp("wheel")
    source = work / "src"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    ignore = shutil.ignore_patterns("__pycache__", "_kernels_aot*", "*.nbi", "*.nbc")
    for name in ("ilcforce", "experiments"):
        shutil.copytree(ROOT / name, source / name, ignore=ignore)
    pip = [sys.executable, "-m", "pip"]
    built = subprocess.run([*pip, "wheel", "-q", "--no-deps", "-w", str(work / "dist"), str(source)],
                           capture_output=True, text=True, timeout=600)
    if built.returncode != 0:  # building needs setuptools>=68 from the package index
        pytest.skip(f"the wheel could not be built here (no package index?): {built.stderr.strip()[-300:]}")
    wheel = next((work / "dist").glob("ilcforce-*.whl"))
    venv = work / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    subprocess.run([*pip, "--python", str(python), "install", "-q", "--no-deps", str(wheel)], check=True,
                   capture_output=True, timeout=300)
    # the dependencies (numpy, numba, ...) from this environment, after the venv's own site-packages:
    # ilcforce itself comes from the wheel (a plain path in a .pth; this environment's editable
    # hook is not run from there)
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    Path(purelib, "zz-ilcforce-test-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    where = subprocess.run([str(python), "-c", "import ilcforce; print(ilcforce.__file__)"], check=True,
                           capture_output=True, text=True, cwd=work).stdout.strip()
    assert Path(where).is_relative_to(venv), f"ilcforce imported from {where}, not from the wheel"
    return venv / "bin"


def _run(bin_dir: Path, args: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["NUMBA_CACHE_DIR"] = str(cwd / "numba-cache")  # the fresh install's kernels, not in the project's cache
    return subprocess.run([str(bin_dir / "ilcforce"), *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=timeout)


def test_the_wheel_ships_the_experiments(installed, tmp_path):
    shown = _run(installed, ["config", "-c", "serial2r"], tmp_path, 120)
    assert shown.returncode == 0, shown.stderr
    assert 'model = "serial2r"' in shown.stdout
    study = _run(installed, ["config", "-c", "paper-mc"], tmp_path, 120)  # a study file is shipped too
    assert study.returncode == 2 and "study" in study.stderr, study.stderr


def test_a_pip_user_simulates_a_shipped_experiment(installed, tmp_path):
    """About 8 s on 2 cores: the fresh install compiles its kernels through numba (no ahead-of-time build)."""
    ran = _run(installed, ["simulate", "-c", "serial2r", "-m", "c1", "--iters", "1", "--results", "results"],
               tmp_path, 900)
    assert ran.returncode == 0, ran.stderr
    assert (tmp_path / "results" / "serial2r" / "c1.h5").is_file()


def test_the_wheel_ships_the_model_files(installed, tmp_path):
    """experiments/models/ installs with the experiments: a pip user loads a shipped robot by its name."""
    code = ("from ilcforce.plants import load_model, shipped_models\nprint(shipped_models())\n"
            "arm = load_model('arm3.urdf', 'tool')\nprint(arm.n, arm.source)")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    done = subprocess.run([str(installed / "python"), "-c", code], capture_output=True, text=True, cwd=tmp_path,
                          env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "'arm3.urdf', 'arm3.xml', 'serial2r.urdf', 'serial2r.xml'" in done.stdout
    n, source = done.stdout.splitlines()[-1].split(" ", 1)
    assert n == "3" and Path(source).is_relative_to(installed.parent), source
