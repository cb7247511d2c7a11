"""Ahead-of-time compiled kernels: a cold command runs the compiled loop without importing numba.

numba's import and its cache loads are about a third of a cold ``ilcforce simulate`` (issue 12).
``make install`` therefore also compiles, once, every built-in law on every built-in plant, the
plants' kernels and the reference's inverse dynamics into one extension module beside this file
(``ilcforce/_kernels_aot*.so``, by :mod:`ilcforce.aot_build` with numba's own compiler, numba.pycc),
which needs only numpy at run time. The kernels are the same functions compiled by the same
compiler, called with the same arguments; the stored numbers are those of the numba run, bit for
bit (``tests/test_aot.py`` compares every law on every plant).

The module is used only when the sources it was built from are the ones here: its stamp
(``_kernels_aot.json``) records a hash of every file whose code it holds (:data:`SOURCES`). After
an edit, a law or plant of one's own, a missing C compiler or ``ILCFORCE_AOT=0`` in the
environment, everything runs through numba as before (same numbers, a slower start); ``make
install`` (or ``python -m ilcforce.aot_build``) builds it again. :func:`status` says which.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import json
import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
MODULE = "ilcforce._kernels_aot"
STAMP = PACKAGE / "_kernels_aot.json"
#: every file whose code the extension module holds (a change to any of them retires it)
SOURCES = ("_jit.py", "aot_build.py", "loop.py", "desired.py", "task.py", "controllers/*.py", "plants/*.py")


def source_fingerprint() -> str:
    """sha256 over the names and bytes of :data:`SOURCES`."""
    digest = hashlib.sha256()
    for pattern in SOURCES:
        for path in sorted(PACKAGE.glob(pattern)):
            digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()


@functools.cache
def _loaded():
    """(the extension module or None, why not)."""
    if os.environ.get("ILCFORCE_AOT", "1").strip() == "0":
        return None, "ILCFORCE_AOT=0"
    try:
        stamp = json.loads(STAMP.read_text())
    except FileNotFoundError:
        return None, "not built (make install builds it)"
    except (OSError, ValueError) as exc:
        return None, f"unreadable stamp {STAMP.name} ({exc})"
    if not isinstance(stamp, dict) or not stamp.get("built"):
        reason = stamp.get("reason", "unknown") if isinstance(stamp, dict) else "malformed stamp"
        return None, f"its build failed ({reason})"
    if stamp.get("fingerprint") != source_fingerprint():
        return None, "built from other sources (make install builds it again)"
    import ilcforce._lapack  # noqa: F401 - the LAPACK module a compiled solve imports, without all of scipy.linalg
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
    return "ahead-of-time compiled (numba not imported)"


def plant_key(plant_cls: type) -> str | None:
    """``fivebar`` for ilcforce's own ``ilcforce.plants.fivebar`` classes; None for any other."""
    prefix = "ilcforce.plants."
    name = plant_cls.__module__
    return name[len(prefix):] if name.startswith(prefix) and name.count(".") == 2 else None


def law_key(controller_cls: type) -> str | None:
    """``c3_c3_law`` for ilcforce's own law ``c3_law`` of ``ilcforce.controllers.c3``; None otherwise."""
    from ilcforce.controllers.base import compiled_law

    for cls in controller_cls.__mro__:
        law = cls.__dict__.get("law")
        if law is not None:
            break
    else:
        return None
    if not isinstance(law, compiled_law):
        return None
    module_name = law.py_func.__module__
    prefix = "ilcforce.controllers."
    if not module_name.startswith(prefix) or module_name.count(".") != 2:
        return None
    return f"{module_name[len(prefix):]}_{law.py_func.__name__}"


def simulator_name(law: str, plant: str) -> str:
    return f"sim__{law}__{plant}"


def simulator(controller, true_plant_cls: type, nominal_plant_cls: type):
    """The compiled loop for this law and plant, taking ``ilcforce.loop._simulate``'s arguments
    after its four kernels; None if there is none (numba's loop is then used)."""
    mod = module()
    if mod is None or true_plant_cls is not nominal_plant_cls:
        return None
    law, plant = law_key(type(controller)), plant_key(true_plant_cls)
    if law is None or plant is None:
        return None
    return getattr(mod, simulator_name(law, plant), None)


@functools.cache
def plant_kernels(plant_cls: type):
    """The plant's five kernels as :class:`~ilcforce.plants.base.PlantKernels` of compiled
    functions callable from Python, or None."""
    from ilcforce.plants.base import PlantKernels

    mod = module()
    plant = plant_key(plant_cls)
    if mod is None or plant is None:
        return None
    found = [getattr(mod, f"{plant}__{kind}", None) for kind in PlantKernels._fields]
    return None if None in found else PlantKernels(*found)


def desired(plant_cls: type):
    """``desired_kernel`` of :mod:`ilcforce.desired` for this plant, without its two kernel
    arguments, or None."""
    mod = module()
    plant = plant_key(plant_cls)
    return None if mod is None or plant is None else getattr(mod, f"desired__{plant}", None)
