"""The ahead-of-time compiled kernels (ilcforce/compiled/aot.py, built by ``make install``): numba's numbers
bit for bit, no numba in a command's process, and numba again whenever the module does not fit."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ilcforce.compiled import aot, sources
from ilcforce.controllers.base import MemoryController
from ilcforce.controllers.nd import compiled_law
from ilcforce.plants import MODELS, plant_class
from ilcforce.plants.base import PlantKernels

_DIGEST = """
import hashlib, sys
import numpy as np
from ilcforce.compiled import aot, sources
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


def _failed_build() -> str | None:
    try:
        stamp = aot.read_stamp()
    except ValueError:
        return None
    return stamp.get("reason") if stamp is not None and stamp.get("built") is False else None


#: the tests that need the module: skipped, with the build's own reason, where it could not be
#: built (no C compiler, a numba without pycc; commands then run through numba, which the rest of
#: the suite tests), failed where it was simply not built or is stale
needs_module = pytest.mark.skipif(_failed_build() is not None,
                                  reason=f"the ahead-of-time build failed here: {_failed_build()}")


@needs_module
def test_the_ahead_of_time_module_is_built_for_these_sources():
    """``make install`` / ``make test`` build it; without it every other test here would compare
    numba with itself."""
    assert aot.module() is not None, f"{aot.status()}: run `make install` (python -m ilcforce.compiled.build)"


@needs_module
def test_every_law_on_every_plant_gives_numbas_numbers_bit_for_bit():
    """Every registered method on both robots, two iterations (the second from the learned
    memory, on the perturbed plant): every log and memory array hashes the same with the
    ahead-of-time kernels (and no numba imported) as with numba's."""
    ahead, jit = _digest("1"), _digest("0")
    assert ahead[1:3] == ["True", "False"], f"the ahead-of-time run used numba: {ahead}"
    assert jit[1:3] == ["False", "True"], f"the numba run did not use numba: {jit}"
    assert ahead[3] == jit[3], "the ahead-of-time kernels compute other numbers than numba's"


_DIGEST_ARM3 = """
import hashlib, sys
from pathlib import Path
import numpy as np
from ilcforce.compiled import aot
from ilcforce.config_load import load_config
from ilcforce.experiment import make_controller, simulate_iterations
from ilcforce.plants.spatial_plant import SpatialArm
digest, used = hashlib.sha256(), []
short = {"experiment.iterations": 2, "reference.duration": 0.05, "plant.perturbation.from_iteration": 1}
config = load_config(Path(sys.argv[1]), short)
for method in ("c1", "c2", "c3", "c3-robust", "pd-ilc"):
    used.append(aot.simulator(make_controller(config, method), SpatialArm, SpatialArm) is not None)
    for record in simulate_iterations(config, method):
        for name in sorted(record.log):
            digest.update(np.ascontiguousarray(record.log[name]).tobytes())
        for name in sorted(record.memory):
            digest.update(np.ascontiguousarray(record.memory[name]).tobytes())
print("DIGEST", all(used), digest.hexdigest())
"""


@needs_module
def test_the_spatial_arms_loop_ahead_of_time_gives_numbas_numbers_bit_for_bit():
    """The spatial arm's loop is in the module, on the one chain kernel every file's arm shares: the same logs
    and memories as numba's loop (its tau_d, Python's, is numba's either way)."""
    experiment = str(Path(__file__).resolve().parent.parent / "experiments" / "arm3.toml")
    runs = []
    for flag in ("1", "0"):
        proc = subprocess.run([sys.executable, "-c", _DIGEST_ARM3, experiment], capture_output=True, text=True,
                              timeout=900, env={**os.environ, "ILCFORCE_AOT": flag})
        assert proc.returncode == 0, proc.stderr
        runs.append(next(line for line in proc.stdout.splitlines() if line.startswith("DIGEST")).split())
    assert runs[0][1] == "True" and runs[1][1] == "False", f"which loop ran: {runs}"
    assert runs[0][2] == runs[1][2], "the spatial arm's ahead-of-time loop computes other numbers than numba's"


@needs_module
def test_the_plant_api_gives_numbas_numbers():
    """The plants' Python API (forward and inverse kinematics, task-space model) through the
    ahead-of-time kernels and through numba's dispatchers, on a grid of poses."""
    for model in MODELS:
        cls = plant_class(model)
        if getattr(cls, "ahead_of_time", True) is not True:  # numba's kernels (a model file's arm), or its loop only
            assert aot.plant_kernels(cls, PlantKernels) is None
            continue
        plant = cls()
        compiled, jitted = aot.plant_kernels(cls, PlantKernels), cls.kernels()
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


@needs_module
def test_a_command_runs_without_importing_numba(tmp_path):
    code = ("import sys\nfrom ilcforce.cli.main import app\n"
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


@needs_module
def test_a_module_built_from_other_sources_is_not_used(stamp):
    record = json.loads(stamp.read_text())
    stamp.write_text(json.dumps({**record, "fingerprint": "0" * 64}))
    assert aot.module() is None
    assert "built from other sources" in aot.status()
    assert aot.simulator(object(), object, object) is None and aot.plant_kernels(plant_class("fivebar"), PlantKernels) is None


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


def test_a_failed_build_is_not_tried_again_at_every_make(stamp, monkeypatch, capsys):
    """Without a C compiler each try costs about 30 s: make's check skips a build that failed for
    the same sources, and says how to try again; other sources are built."""
    from ilcforce.compiled import build as aot_build

    tries: list[int] = []

    def no_compiler():
        tries.append(1)
        raise RuntimeError("no compiler")

    monkeypatch.setattr(aot_build, "_exports", no_compiler)
    stamp.write_text(json.dumps({"built": False, "reason": "CompileError: no compiler",
                                 "fingerprint": aot.source_fingerprint()}))
    assert aot_build.build() is False and tries == []
    err = capsys.readouterr().err
    assert "CompileError: no compiler" in err and "--force" in err
    stamp.write_text(json.dumps({"built": False, "reason": "old", "fingerprint": "0" * 64}))  # other sources
    assert aot_build.build() is False and tries == [1]
    assert json.loads(stamp.read_text())["reason"] == "RuntimeError: no compiler"
    assert aot_build.build(force=True) is False and tries == [1, 1]


@needs_module
@pytest.mark.parametrize("value, on", [("0", False), ("false", False), (" Off ", False), ("no", False),
                                       ("1", True), ("", True)])
def test_ilcforce_aot_turns_it_off(stamp, monkeypatch, value, on):
    monkeypatch.setenv("ILCFORCE_AOT", value)
    assert (aot.module() is not None) is on
    if not on:
        assert f"ILCFORCE_AOT={value.strip()}" in aot.status()


@needs_module
def test_a_damaged_module_is_never_loaded(stamp, tmp_path, monkeypatch):
    """Loading a truncated shared object crashes the process (SIGBUS in dlopen): the module's
    sha256 in the stamp must match before it is imported."""
    damaged = tmp_path / aot.module_path().name
    damaged.write_bytes(aot.module_path().read_bytes()[:600_000])
    monkeypatch.setattr(aot, "module_path", lambda: damaged)
    assert aot.module() is None
    assert "is not the module that was built" in aot.status()
    assert aot.stamp_problem() is not None  # make's check (the same one) rebuilds it


def _no_hashing(monkeypatch):
    def refuse(*args):
        raise AssertionError("hashed")
    monkeypatch.setattr(aot, "source_fingerprint", refuse)
    monkeypatch.setattr(aot, "file_digest", refuse)


@needs_module
def test_files_unchanged_since_the_build_are_not_hashed_again(stamp, monkeypatch):
    """A cold command checks the files' identities (size, times, inode) recorded by the build, not
    their sha256 (about 15 ms with hashlib's import); hashlib is not imported."""
    assert aot.identities_match(json.loads(stamp.read_text()))
    _no_hashing(monkeypatch)
    assert aot.module() is not None
    code = "import sys\nfrom ilcforce.compiled import aot\nassert aot.module() is not None\nprint('hashlib' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "False", proc.stderr


@needs_module
@pytest.mark.parametrize("change", ["a source rewritten", "a new source", "no identities", "identities of other hashes"])
def test_other_files_are_hashed_again(stamp, monkeypatch, change):
    record = json.loads(stamp.read_text())
    files = dict(record["files"])
    if change == "a source rewritten":
        files["controllers/c3.py"] = [*files["controllers/c3.py"][:2], files["controllers/c3.py"][2] + 1,
                                      *files["controllers/c3.py"][3:]]  # its ctime moved
    elif change == "a new source":
        files["plants/mine.py"] = [1, 2, 3, 4, 5]
    if change == "no identities":
        record = {k: v for k, v in record.items() if k not in ("files", "files_for")}
    elif change == "identities of other hashes":
        record["files_for"] = ["0" * 64, record["module_sha256"]]
    else:
        monkeypatch.setattr(aot, "file_identities", lambda: files)
    stamp.write_text(json.dumps(record))
    assert not aot.identities_match(record)
    hashed = []
    real = aot.file_digest
    monkeypatch.setattr(aot, "file_digest", lambda path: hashed.append(path) or real(path))
    assert aot.module() is not None  # same bytes: hashed, found equal, used
    assert hashed == [aot.module_path()]


def test_a_rewrite_with_the_same_bytes_changes_the_identity(tmp_path, monkeypatch):
    """The premise: writing a file changes its identity even with the same bytes, size and mtime."""
    import shutil

    copy = tmp_path / "ilcforce"
    shutil.copytree(aot.PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.json"))
    monkeypatch.setattr(aot, "PACKAGE", copy)
    monkeypatch.setattr(sources, "PACKAGE", copy)
    if not aot.module_path().exists():
        aot.module_path().write_bytes(b"")
    before = aot.file_identities()
    source = copy / "controllers" / "c3.py"
    info = os.stat(source)
    source.write_bytes(source.read_bytes())
    os.utime(source, ns=(info.st_atime_ns, info.st_mtime_ns))
    after = aot.file_identities()
    assert after["controllers/c3.py"][:2] == before["controllers/c3.py"][:2]  # same size, same mtime
    assert after != before


@needs_module
def test_the_build_records_the_identities_in_an_older_stamp(stamp, monkeypatch):
    """A stamp written before identities were recorded gets them at the next make, without a rebuild."""
    from ilcforce.compiled import build as aot_build

    record = json.loads(stamp.read_text())
    stamp.write_text(json.dumps({k: v for k, v in record.items() if k not in ("files", "files_for")}))
    monkeypatch.setattr(aot_build, "_exports", lambda: (_ for _ in ()).throw(AssertionError("rebuilt")))
    assert aot_build.build(verbose=False) is True
    assert aot.identities_match(json.loads(stamp.read_text()))
    assert json.loads(stamp.read_text())["module_sha256"] == record["module_sha256"]


@pytest.mark.parametrize("kind", ["fifo", "directory", "huge", "nested"])
def test_a_stamp_that_is_not_one_is_refused_at_once(stamp, kind):
    """A FIFO (would block for ever), a folder, a huge file, JSON nested past the recursion limit."""
    stamp.unlink()
    if kind == "fifo":
        os.mkfifo(stamp)
    elif kind == "directory":
        stamp.mkdir()
    elif kind == "huge":
        stamp.write_text(json.dumps({"built": True, "pad": "x" * 200_000}))
    else:
        stamp.write_text("[" * 100_000 + "]" * 100_000)
    assert aot.module() is None
    assert "unreadable stamp" in aot.status()


def test_the_fingerprint_skips_editor_files(tmp_path, monkeypatch):
    """Emacs keeps ``.#c3.py``, a dangling link, beside a file with unsaved edits: it is not a source."""
    import shutil

    copy = tmp_path / "ilcforce"
    shutil.copytree(aot.PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.json"))
    monkeypatch.setattr(aot, "PACKAGE", copy)
    monkeypatch.setattr(sources, "PACKAGE", copy)
    clean = aot.source_fingerprint.__wrapped__()
    (copy / "controllers" / ".#c3.py").symlink_to("root@host.1234:1700000000")
    (copy / "plants" / "odd.py").mkdir()
    assert aot.source_fingerprint.__wrapped__() == clean is not None
    (copy / "controllers" / "c3.py").write_text((copy / "controllers" / "c3.py").read_text() + "\n# edited\n")
    assert aot.source_fingerprint.__wrapped__() != clean


def test_numbas_cache_is_kept_per_version_of_the_kernel_sources(tmp_path, monkeypatch):
    """numba finds a cached kernel stale only when its own file changed, not when a kernel it
    calls did; a cache folder per fingerprint of every kernel source makes any edit start afresh."""
    from ilcforce.compiled import jit as _jit

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    _jit._key_the_cache()
    keyed = os.environ["NUMBA_CACHE_DIR"]
    assert keyed == str(tmp_path / f"ilcforce-sources-{aot.source_fingerprint()[:16]}")
    _jit._key_the_cache()  # a child process, which inherits the keyed folder, keeps it
    assert os.environ["NUMBA_CACHE_DIR"] == keyed


def test_a_placeholder_pickles_by_reference():
    code = ("import pickle, sys\nfrom ilcforce.controllers import base\n"
            "assert type(base.sgn).__name__ == 'LazyKernel' and 'numba' not in sys.modules\n"
            "assert pickle.loads(pickle.dumps(base.sgn)) is base.sgn\nprint('OK')")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "OK" in proc.stdout, proc.stderr


@needs_module
def test_a_law_set_on_the_controller_object_runs_through_numba():
    """``controller.law = my_law`` (as tests/test_simulate.py does) must run my_law, not the class's."""
    from ilcforce.config_load import load_config
    from ilcforce.experiment import make_controller

    controller = make_controller(load_config(None, {}), "c1")
    fivebar = plant_class("fivebar")
    assert aot.simulator(controller, fivebar, fivebar) is not None
    controller.law = object()
    assert aot.simulator(controller, fivebar, fivebar) is None


def _own_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    return 0


class _OwnController(MemoryController):
    law = compiled_law(_own_law)


def test_a_law_of_ones_own_runs_through_numba():
    """Only ilcforce's own laws and plants are compiled ahead of time; any other is numba's."""
    assert aot.law_key(_OwnController) is None
    assert aot.simulator(_OwnController.__new__(_OwnController), plant_class("fivebar"), plant_class("fivebar")) is None
    from ilcforce.controllers import REGISTRY

    assert aot.law_key(REGISTRY["c3"].controller_class) == "c3_c3_law"


def test_numba_objects_replace_the_placeholders_once_numba_is_imported():
    """ilcforce/compiled/jit.py: after numba's import every kernel module global is numba's own object (a
    kernel compiled later finds real dispatchers among its globals)."""
    from ilcforce import task
    from ilcforce.compiled import jit as _jit
    from ilcforce.plants import base

    nb = _jit.numba()
    from numba.core.dispatcher import Dispatcher

    assert isinstance(task.wall_force, Dispatcher)
    assert base.carray is nb.carray
    assert not any(isinstance(v, _jit._Placeholder) for m in list(sys.modules.values())
                   if getattr(m, "__name__", "").startswith("ilcforce") for v in vars(m).values())
