"""Ahead-of-time compiled kernels: a cold command runs the compiled loop without importing numba.

numba's import and its cache loads are about a third of a cold ``ilcforce simulate``.
``make install`` therefore also compiles, once, every built-in law on every built-in plant, the
plants' kernels and the reference's inverse dynamics into one extension module beside this file
(``ilcforce/_kernels_aot*.so``, by :mod:`ilcforce.compiled.build` with numba's own compiler, numba.pycc),
which needs only numpy at run time. The kernels are the same functions compiled by the same
compiler, called with the same arguments; the stored numbers are those of the numba run, bit for
bit (``tests/test_aot.py`` compares every law on every plant).

The module is used only when the sources it was built from are the ones here: its stamp
(``_kernels_aot.json``) records a hash of every file whose code it holds (:data:`SOURCES`). After
an edit, a law or plant of one's own, a missing C compiler or ``ILCFORCE_AOT=0`` in the
environment, everything runs through numba as before (same numbers, a slower start); ``make
install`` (or ``python -m ilcforce.compiled.build``) builds it again. :func:`status` says which.
"""

from __future__ import annotations

import functools
import importlib
import importlib.machinery
import json
import os
import stat
from pathlib import Path

from ilcforce.compiled.sources import PACKAGE, SOURCES, source_files, source_fingerprint  # noqa: F401 - the stamp records it

MODULE = "ilcforce._kernels_aot"
STAMP = PACKAGE / "_kernels_aot.json"


#: ``ILCFORCE_AOT`` values that turn the ahead-of-time kernels off (case and spaces ignored)
OFF = ("0", "false", "no", "off")
#: a stamp is a few hundred bytes; anything much larger is not one
_STAMP_LIMIT = 1 << 16


def module_path() -> Path:
    """Where the extension module for this Python is (or would be)."""
    return PACKAGE / (MODULE.rpartition(".")[2] + importlib.machinery.EXTENSION_SUFFIXES[0])


def file_digest(path: Path) -> str:
    """sha256 of a file's bytes (the module's: a truncated or replaced module is not loaded, since
    loading a damaged shared object can crash the process)."""
    import hashlib

    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _identity(path: Path) -> list[int]:
    """What changes whenever a file's bytes do (or the file is replaced): size, mtime, ctime, inode, device."""
    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise OSError(f"{path.name} is not a regular file")
    return [info.st_size, info.st_mtime_ns, info.st_ctime_ns, info.st_ino, info.st_dev]


def file_identities() -> dict[str, list[int]]:
    """:func:`_identity` of every file of :data:`SOURCES` and of the module, by name (OSError if one
    is missing). Taken before the files are hashed, a build records them in the stamp."""
    files = {path.relative_to(PACKAGE).as_posix(): _identity(path) for path in source_files()}
    files[module_path().name] = _identity(module_path())
    return files


def identities_match(stamp: dict) -> bool:
    """Whether every file is the very one the stamp's hashes were taken of, so that hashing them again
    (about 15 ms of a cold command, hashlib's import included) would give the same: the stamp's
    ``files`` (taken before the hashes, for those hashes: ``files_for``) equal the files' identities
    now, the same set of files. A write through ``write()`` or ``truncate()`` changes the file's ctime,
    which no user can set back, and a file put in its place has another inode. Not seen: a write
    through a shared memory mapping of a page already dirty, two same-size writes within one tick of
    a coarse ctime clock around ``make install``, damage below the file system; for those,
    ``python -m ilcforce.compiled.build --force`` builds the module again, or ``ILCFORCE_AOT=0`` leaves it."""
    files = stamp.get("files")
    if not isinstance(files, dict) or stamp.get("files_for") != [stamp.get("fingerprint"), stamp.get("module_sha256")]:
        return False
    try:
        return file_identities() == files
    except OSError:
        return False


def read_stamp() -> dict | None:
    """The stamp as a dict; None if there is none; ValueError naming what is wrong with it."""
    try:
        fd = os.open(STAMP, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ValueError(exc.strerror or str(exc)) from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ValueError("not a regular file")
        if info.st_size > _STAMP_LIMIT:
            raise ValueError(f"{info.st_size} bytes, not a stamp")
        data = os.read(fd, _STAMP_LIMIT + 1)
    except OSError as exc:
        raise ValueError(exc.strerror or str(exc)) from None
    finally:
        os.close(fd)
    try:
        stamp = json.loads(data)
    except (ValueError, RecursionError):
        raise ValueError("not JSON") from None
    if not isinstance(stamp, dict):
        raise ValueError("malformed stamp")
    return stamp


def stamp_problem() -> str | None:
    """Why the built module does not fit the sources here (None: it does). The one check both
    the loader and the build's "is it current?" use."""
    try:
        stamp = read_stamp()
    except ValueError as exc:
        return f"unreadable stamp {STAMP.name} ({exc})"
    if stamp is None:
        return "not built (make install builds it)"
    if stamp.get("built") is not True:
        return f"its build failed ({stamp.get('reason', 'unknown')})"
    if identities_match(stamp):
        return None
    fingerprint = source_fingerprint()
    if fingerprint is None or stamp.get("fingerprint") != fingerprint:
        return "built from other sources (make install builds it again)"
    path = module_path()
    try:
        if not (stat.S_ISREG(os.stat(path).st_mode) and file_digest(path) == stamp.get("module_sha256")):
            return f"{path.name} is not the module that was built (make install builds it again)"
    except OSError as exc:
        return f"{path.name}: {exc.strerror or exc} (make install builds it again)"
    return None


@functools.cache
def _loaded():
    """(the extension module or None, why not)."""
    if os.environ.get("ILCFORCE_AOT", "1").strip().lower() in OFF:
        return None, f"ILCFORCE_AOT={os.environ['ILCFORCE_AOT'].strip()}"
    problem = stamp_problem()
    if problem is not None:
        return None, problem
    try:
        return importlib.import_module(MODULE), ""
    except ImportError as exc:
        return None, f"cannot be loaded ({exc})"


def module():
    """The extension module, or None when the kernels run through numba."""
    return _loaded()[0]


def status() -> str:
    """One line: which kernels a command runs, and why not the ahead-of-time ones."""
    mod, why = _loaded()
    if mod is None:
        return f"numba (ahead-of-time kernels not used: {why})"
    return "ahead-of-time compiled (no numba needed)"


def plant_key(plant_cls: type) -> str | None:
    """``fivebar`` for ilcforce's own ``ilcforce.plants.fivebar`` classes; None for any other."""
    prefix = "ilcforce.plants."
    name = plant_cls.__module__
    return name[len(prefix):] if name.startswith(prefix) and name.count(".") == 2 else None


def law_key(controller) -> str | None:
    """``c3_c3_law`` when the law a controller (object or class) runs is ilcforce's own ``c3_law``
    of ``ilcforce.controllers.c3`` (a compiled law: it has ``py_func``); None for any other (one set
    on the object itself included)."""
    cls = controller if isinstance(controller, type) else type(controller)
    spaces = [vars(c) for c in cls.__mro__]
    if not isinstance(controller, type):
        spaces.insert(0, getattr(controller, "__dict__", {}))
    law = next((space["law"] for space in spaces if "law" in space), None)
    py_func = getattr(law, "py_func", None) if not isinstance(law, (staticmethod, classmethod)) else None
    if py_func is None or not callable(py_func):
        return None
    module_name = py_func.__module__
    prefix = "ilcforce.controllers."
    if not module_name.startswith(prefix) or module_name.count(".") != 2:
        return None
    return f"{module_name[len(prefix):]}_{py_func.__name__}"


def simulator_name(law: str, plant: str) -> str:
    return f"sim__{law}__{plant}"


def simulator(controller, true_plant_cls: type, nominal_plant_cls: type):
    """The compiled loop for this law and plant, taking the arguments of ``ilcforce.loop.simulator``'s entry
    after its three kernels (the law, the true and the nominal plant's ``nd_dyn``); None if there is none
    (numba's loop is then used)."""
    mod = module()
    if mod is None or true_plant_cls is not nominal_plant_cls:
        return None
    law, plant = law_key(controller), plant_key(true_plant_cls)
    if law is None or plant is None:
        return None
    return getattr(mod, simulator_name(law, plant), None)


@functools.cache
def plant_kernels(plant_cls: type, kind: type):
    """The plant's five kernels as ``kind`` (the plants' kernel tuple, whose fields name them) of
    compiled functions callable from Python, or None."""
    mod = module()
    plant = plant_key(plant_cls)
    if mod is None or plant is None:
        return None
    found = [getattr(mod, f"{plant}__{name}", None) for name in kind._fields]
    return None if None in found else kind(*found)


def desired(plant_cls: type):
    """``desired_kernel`` of :mod:`ilcforce.plants.desired` for this plant, without its two kernel
    arguments, or None.

    Its solves call LAPACK through ``scipy.linalg.cython_lapack``, which the module imports at the
    first solve: :mod:`ilcforce.compiled.lapack` loads it first, without all of scipy.linalg. Only this
    kernel solves, so the module itself loads without it (9-12 ms less before a run's first loop;
    a run makes tau_d in its inputs thread, while iteration 0 simulates)."""
    mod = module()
    plant = plant_key(plant_cls)
    if mod is None or plant is None:
        return None
    import ilcforce.compiled.lapack  # noqa: F401 - the LAPACK module a compiled solve imports, without all of scipy.linalg

    return getattr(mod, f"desired__{plant}", None)
