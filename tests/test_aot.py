"""The ahead-of-time compiled kernels (ilcforce/aot.py, built by ``make install``): numba's numbers
bit for bit, no numba in a command's process, and numba again whenever the module does not fit."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from ilcforce import aot
from ilcforce.controllers.base import MemoryController, compiled_law
from ilcforce.plants import MODELS, plant_class

_DIGEST = """
import hashlib, sys
import numpy as np
from ilcforce import aot
from ilcforce.config_load import load_config
from ilcforce.controllers import REGISTRY
from ilcforce.experiment import simulate_iterations
digest = hashlib.sha256()
short = {"experiment.iterations": 2, "reference.duration": 0.05, "plant.perturbation.from_iteration": 1}
for model in ("fivebar", "serial2r"):
    for method in REGISTRY:
        for record in simulate_iterations(load_config(None, {**short, "plant.model": model}), method):
            for name in sorted(record.log):
                digest.update(np.ascontiguousarray(record.log[name]).tobytes())
            for name in sorted(record.memory):
                digest.update(np.ascontiguousarray(record.memory[name]).tobytes())
print("DIGEST", aot.module() is not None, "numba" in sys.modules, digest.hexdigest())
"""


def _digest(aot_env: str) -> list[str]:
    env = {**os.environ, "ILCFORCE_AOT": aot_env}
    proc = subprocess.run([sys.executable, "-c", _DIGEST], capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr
    return next(line for line in proc.stdout.splitlines() if line.startswith("DIGEST")).split()


def test_the_ahead_of_time_module_is_built_for_these_sources():
    """``make install`` / ``make test`` build it; without it every other test here would compare
    numba with itself."""
    assert aot.module() is not None, f"{aot.status()}: run `make install` (python -m ilcforce.aot_build)"


def test_every_law_on_every_plant_gives_numbas_numbers_bit_for_bit():
    """Every registered method on both robots, two iterations (the second from the learned
    memory, on the perturbed plant): every log and memory array hashes the same with the
    ahead-of-time kernels (and no numba imported) as with numba's."""
    ahead, jit = _digest("1"), _digest("0")
    assert ahead[1:3] == ["True", "False"], f"the ahead-of-time run used numba: {ahead}"
    assert jit[1:3] == ["False", "True"], f"the numba run did not use numba: {jit}"
    assert ahead[3] == jit[3], "the ahead-of-time kernels compute other numbers than numba's"


def test_the_plant_api_gives_numbas_numbers():
    """The plants' Python API (forward and inverse kinematics, task-space model) through the
    ahead-of-time kernels and through numba's dispatchers, on a grid of poses."""
    for model in MODELS:
        cls = plant_class(model)
        plant = cls()
        compiled, jitted = aot.plant_kernels(cls), cls.kernels()
        assert compiled is not None
        for th1 in np.linspace(0.3, 2.0, 5):
            for th2 in np.linspace(0.8, 2.6, 5):
                same = np.array_equal  # a pose outside the working mode gives ok = 0 and NaN, the same way
                assert same(compiled.kin(plant.address, th1, th2), jitted.kin(plant.address, th1, th2), equal_nan=True)
                for d in (-0.7, 0.0, 1.3):
                    args = (plant.address, th1, th2, d, -d)
                    for kind in ("accel", "task", "dyn"):
                        a, b = getattr(compiled, kind)(*args), getattr(jitted, kind)(*args)
                        assert same(a, b, equal_nan=True), (model, kind, args)
                ok, px, py = jitted.kin(plant.address, th1, th2)[:3]
                if ok:
                    assert same(compiled.ik(plant.address, px, py), jitted.ik(plant.address, px, py), equal_nan=True)


def test_a_command_runs_without_importing_numba(tmp_path):
    code = ("import sys\nfrom ilcforce.cli import app\n"
            f"sys.argv = ['ilcforce', 'simulate', '--method', 'c3', '--iters', '2', '--out', {str(tmp_path / 'c3.h5')!r}]\n"
            "try:\n    app()\nexcept SystemExit as exc:\n    assert not exc.code, exc.code\n"
            "print('NUMBA', 'numba' in sys.modules, 'llvmlite' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "ILCFORCE_AOT": "1"})
    assert proc.returncode == 0, proc.stderr
    assert "NUMBA False False" in proc.stdout


@pytest.fixture
def stamp(tmp_path, monkeypatch):
    """aot's stamp moved to a scratch file; the loaded module forgotten before and after."""
    path = tmp_path / "_kernels_aot.json"
    path.write_text(aot.STAMP.read_text())
    monkeypatch.setattr(aot, "STAMP", path)
    aot._loaded.cache_clear()
    aot.plant_kernels.cache_clear()
    yield path
    aot._loaded.cache_clear()
    aot.plant_kernels.cache_clear()


def test_a_module_built_from_other_sources_is_not_used(stamp):
    record = json.loads(stamp.read_text())
    stamp.write_text(json.dumps({**record, "fingerprint": "0" * 64}))
    assert aot.module() is None
    assert "built from other sources" in aot.status()
    assert aot.simulator(object(), object, object) is None and aot.plant_kernels(plant_class("fivebar")) is None


@pytest.mark.parametrize("content, why", [
    (None, "not built"),
    ('{"built": false, "reason": "CompileError: no compiler", "fingerprint": ""}', "build failed (CompileError"),
    ("{not json", "unreadable stamp"),
    ("[1, 2]", "malformed stamp"),
])
def test_without_a_usable_module_the_kernels_run_through_numba(stamp, content, why):
    if content is None:
        stamp.unlink()
    else:
        stamp.write_text(content)
    assert aot.module() is None
    assert why in aot.status()


def test_ilcforce_aot_0_turns_it_off(stamp, monkeypatch):
    monkeypatch.setenv("ILCFORCE_AOT", "0")
    assert aot.module() is None and "ILCFORCE_AOT=0" in aot.status()


def _own_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    return 0.0, 0.0


class _OwnController(MemoryController):
    law = compiled_law(_own_law)


def test_a_law_of_ones_own_runs_through_numba():
    """Only ilcforce's own laws and plants are compiled ahead of time; any other is numba's."""
    assert aot.law_key(_OwnController) is None
    assert aot.simulator(_OwnController.__new__(_OwnController), plant_class("fivebar"), plant_class("fivebar")) is None
    from ilcforce.controllers import REGISTRY

    assert aot.law_key(REGISTRY["c3"].controller_class) == "c3_c3_law"


def test_numba_objects_replace_the_placeholders_once_numba_is_imported():
    """ilcforce/_jit.py: after numba's import every kernel module global is numba's own object (a
    kernel compiled later finds real dispatchers among its globals)."""
    from ilcforce import _jit, task
    from ilcforce.plants import base

    nb = _jit.numba()
    from numba.core.dispatcher import Dispatcher

    assert isinstance(task.wall_force, Dispatcher)
    assert base.carray is nb.carray
    assert not any(isinstance(v, _jit._Placeholder) for m in list(sys.modules.values())
                   if getattr(m, "__name__", "").startswith("ilcforce") for v in vars(m).values())
