"""Lazy imports: each path imports only what it uses, so cold commands start fast.

Timings belong to `make bench` (benchmarks/cold.py); this pins the structure that makes them:
which heavy modules each path leaves unimported. A failure names the module that crept in.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

HEAVY = ("rich.table", "rich.progress", "pandas", "numba", "h5py", "matplotlib", "scipy", "mujoco")


def _imported_after(code: str) -> set[str]:
    probe = f"{code}\nimport sys\nprint('MODULES:', *(m for m in {HEAVY!r} if m in sys.modules))"
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    line = [line for line in proc.stdout.splitlines() if line.startswith("MODULES:")][-1]
    return set(line.split()[1:])


@pytest.mark.parametrize("argv", [["--help"], ["simulate", "--help"], ["compare", "--help"], ["version"]])
def test_help_and_version_import_no_heavy_module(argv):
    code = (f"import sys\nsys.argv = ['ilcforce', *{argv!r}]\nfrom ilcforce.cli.main import app\n"  # main() would os._exit
            "try:\n    app()\nexcept SystemExit:\n    pass")
    assert _imported_after(code) - {"rich.table"} == set()  # typer's help may draw a rich table


def test_the_simulation_path_imports_neither_pandas_nor_matplotlib():
    assert _imported_after("import ilcforce.experiment") & {"pandas", "matplotlib"} == set()


def test_compare_prints_its_table_without_pandas(tmp_path):
    """compare's table comes from the stores' metrics rows (ilcforce/report/comparison.py): pandas'
    import (about 0.2 s of CPU beside the workers) is not part of the command."""
    argv = ["compare", "--methods", "c1,c3", "--iters", "2", "--set", "reference.duration=0.05",
            "--results", str(tmp_path)]
    code = (f"import sys\nsys.argv = ['ilcforce', *{argv!r}]\nfrom ilcforce.cli.main import app\n"
            "try:\n    app()\nexcept SystemExit as exc:\n    assert not exc.code, exc.code")
    assert _imported_after(code) & {"pandas", "matplotlib"} == set()
    assert sorted(p.name for p in (tmp_path / "paper--reference.duration=0.05").glob("*.h5")) == ["c1.h5", "c3.h5"]


def test_compare_tables_do_not_import_matplotlib():
    assert "matplotlib" not in _imported_after("import ilcforce.report.tables")


@pytest.mark.parametrize("ahead_of_time", ["1", "0"])
def test_a_simulation_loads_numbas_lapack_without_all_of_scipy_linalg(ahead_of_time):
    """ilcforce.compiled.lapack: numba's BLAS/LAPACK modules come without scipy.linalg's 170 ms package
    import, and the compiled solves still work (the tau_d kernel uses np.linalg.solve), with the
    ahead-of-time kernels (ilcforce/compiled/aot.py) and with numba's."""
    code = ("import sys\nfrom ilcforce.config_load import load_config\n"
            "from ilcforce.experiment import simulate_iterations\n"
            "cfg = load_config(None, {'experiment.iterations': 1, 'reference.duration': 0.05})\n"
            "rec = next(simulate_iterations(cfg, 'c3'))\n"
            "import numpy as np\nassert np.isfinite(rec.log['desired_torque']).all()\n"
            "print('LINALG', 'scipy.linalg' in sys.modules, 'scipy.linalg.cython_lapack' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "ILCFORCE_AOT": ahead_of_time})
    assert proc.returncode == 0, proc.stderr
    assert "LINALG False True" in proc.stdout


def test_a_compile_is_announced_once(monkeypatch):
    """A first run after an install compiles for about a minute with the progress display at 0; the
    terminal now says so, once (ilcforce/compiled/note.py). The listener waits for numba's import
    (a run of ahead-of-time kernels imports none)."""
    from ilcforce.compiled import jit as _jit, note as compile_note

    monkeypatch.setattr(compile_note, "_asked", [])
    monkeypatch.setattr(compile_note, "_installed", [])
    # a fresh process: no listener waiting for numba yet (the CLI tests' commands asked for one each
    # time this process's state was reset, since every command asks; only compile_note waits there)
    monkeypatch.setattr(_jit, "_on_load", [])
    lines: list[str] = []
    compile_note.announce_compiles(lines.append)
    compile_note.announce_compiles(lines.append)  # a second call adds no second listener
    njit = _jit.numba().njit  # numba imported (or already): the listener is in place
    from numba.core import event

    assert len(compile_note._installed) == 1
    try:
        @njit(cache=False)
        def plus_one(x):
            return x + 1

        assert lines == []
        assert plus_one(1) == 2 and plus_one(2.5) == 3.5  # two compiles (int, float): one line
        assert lines == [compile_note.NOTE]
    finally:
        event.unregister("numba:compile", compile_note._installed[0])


@pytest.mark.parametrize("ahead_of_time", ["1", "0"])
def test_a_five_bar_run_neither_imports_mujoco_nor_compiles_the_chain_kernels(ahead_of_time):
    """The robots read from model files (ilcforce/plants/model_plant.py) cost the paper's robot nothing:
    no MuJoCo, and none of the chain kernels (ilcforce/plants/chain.py, planar_kernels.py) compiled or
    loaded, with the ahead-of-time kernels and with numba's."""
    code = ("import sys\nfrom ilcforce.config_load import load_config\n"
            "from ilcforce.experiment import simulate_iterations\n"
            "cfg = load_config(None, {'experiment.iterations': 1, 'reference.duration': 0.05})\n"
            "rec = next(simulate_iterations(cfg, 'c3'))\n"
            "from ilcforce.plants import chain, planar_kernels\n"
            "kernels = [getattr(m, n) for m in (chain, planar_kernels) for n in dir(m)]\n"
            "compiled = [k.py_func.__name__ for k in kernels if getattr(k, 'signatures', None)]\n"
            "print('COMPILED', compiled, 'mujoco' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "ILCFORCE_AOT": ahead_of_time})
    assert proc.returncode == 0, proc.stderr
    assert "COMPILED [] False" in proc.stdout, proc.stdout
