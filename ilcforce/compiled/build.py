"""Build the ahead-of-time kernels of :mod:`ilcforce.compiled.aot` (``make install`` runs it).

    python -m ilcforce.compiled.build [--force]

A build that is current (same sources, same module) is not repeated, nor is one that failed for
the same sources; ``--force`` builds anyway.

Compiles with numba.pycc, into ``ilcforce/_kernels_aot*.so`` beside the package's sources:

* ``sim__<law>__<plant>``: the compiled loop (``ilcforce.loop.simulator`` for the plant's task
  dimension) with that law and that plant's ``nd_dyn`` kernel bound (every built-in law on every built-in
  plant), taking the loop's other arguments;
* ``<plant>__kin`` ... ``<plant>__ik``: the plant's kernels (for the plant's Python API);
* ``desired__<plant>``: ``ilcforce.plants.desired.desired_kernel`` with the plant's kernels bound.

Each export calls the very dispatchers numba runs (same source, same compiler, same options), so
the numbers are numba's. The code is built for the generic CPU of the machine's architecture
(pycc's default: no instruction-set extensions), so the module runs on any machine that runs this
Python. Then the stamp ``_kernels_aot.json`` records the sources' fingerprint and the module's
sha256. A build that fails (no C compiler, a numba without pycc) records why and exits 0: commands
then run through numba as before.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

from ilcforce.compiled import aot, jit as _jit


def _exports():
    """(name, signature, python function) of every export."""
    nb = _jit.numba()
    types = nb.types
    from ilcforce import loop
    from ilcforce.plants import desired
    from ilcforce.controllers import REGISTRY
    from ilcforce.plants import MODELS, plant_class
    from ilcforce.plants.base import PlantKernels, kernel_signature

    laws = {}
    for spec in REGISTRY.shipped_specs():  # ilcforce's own laws; a plugin's runs through numba (no law_key)
        cls = spec.controller_class
        key = aot.law_key(cls)
        if key is not None:
            laws[key] = cls.law
    desired_sig = types.int64(*desired.desired_kernel.signatures[0][2:])
    desired_kernel = desired.desired_kernel
    out = []
    for model in MODELS:
        cls = plant_class(model)
        mode = getattr(cls, "ahead_of_time", True)
        if not mode:  # numba's kernels only (e.g. a planar model file's arm)
            continue
        plant = aot.plant_key(cls)
        if mode == "loop":  # the loop alone, on one kernel every instance shares (a spatial arm: any file's chain)
            simulate = loop.simulator(cls.dimension)
            sim_sig = types.UniTuple(types.int64, 2)(*simulate.signatures[0][3:])
            for key, law in laws.items():
                out.append((aot.simulator_name(key, plant), sim_sig, _bind_loop(simulate, law, cls.shared_nd_kernel())))
            continue
        kernels = cls.kernels()
        for kind, kernel in zip(PlantKernels._fields, kernels):
            out.append((f"{plant}__{kind}", kernel_signature(kind.upper()), kernel.py_func))
        out.append((f"desired__{plant}", desired_sig, _bind_desired(desired_kernel, kernels)))
        # the loop's entry for the plant's task dimension; a dispatcher's ``signatures``: the argument types of
        # each compiled signature (numba's public API)
        simulate = loop.simulator(cls.dimension)
        sim_sig = types.UniTuple(types.int64, 2)(*simulate.signatures[0][3:])
        for key, law in laws.items():
            out.append((aot.simulator_name(key, plant), sim_sig, _bind_loop(simulate, law, cls.nd_kernel())))
    return out


def _bind_loop(simulate, law, dyn):
    def bound(p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset, iset, log, carry, work,
              k_start, k_stop):
        return simulate(law, dyn, dyn, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset, iset,
                        log, carry, work, k_start, k_stop)
    return bound


def _bind_desired(desired_kernel, kernels):
    dyn, ik = kernels.dyn, kernels.ik

    def bound(p, ref, w, tau_d, task_d):
        return desired_kernel(dyn, ik, p, ref, w, tau_d, task_d)
    return bound


@contextlib.contextmanager
def _releasing_the_gil():
    """Exports that release the GIL while they run, as numba's ``nogil=True``: the store's writes
    and the next iteration's simulation overlap (ilcforce/pipeline.py). pycc has no option for it;
    its compiler takes numba's compile flags from ``Flags()``, and ``release_gil`` is the flag
    ``nogil=True`` sets. The one patch of numba in ilcforce, for the build only: numba is pinned
    below the next release (pyproject.toml) and tests/test_private_imports.py checks that the
    installed numba still makes its flags so; docs/design.md has the plan for pycc's removal."""
    from numba.pycc import compiler

    plain = compiler.Flags

    class NoGilFlags(plain):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.release_gil = True

    compiler.Flags = NoGilFlags
    try:
        yield
    finally:
        compiler.Flags = plain


def _write_stamp(stamp: dict) -> None:
    fd, partial = tempfile.mkstemp(prefix=f".{aot.STAMP.name}.", dir=aot.STAMP.parent)
    with os.fdopen(fd, "w") as handle:
        handle.write(json.dumps(stamp, indent=1) + "\n")
    os.chmod(partial, 0o644)
    os.replace(partial, aot.STAMP)


def _record_identities() -> None:
    """Add the files' identities to a current stamp (:func:`ilcforce.compiled.aot.identities_match`), so that a
    command need not hash them again. They are taken first, then the files hashed: a file changed in
    between has another identity than the one recorded, and is hashed again at its next use."""
    try:
        files = aot.file_identities()
        stamp = aot.read_stamp()
    except (OSError, ValueError):
        return
    if stamp is None or stamp.get("built") is not True or aot.identities_match(stamp):
        return
    fingerprint = aot.source_fingerprint.__wrapped__()  # hashed after the identities were taken
    if fingerprint != stamp.get("fingerprint") or aot.file_digest(aot.module_path()) != stamp.get("module_sha256"):
        return
    _write_stamp({**stamp, "files": files, "files_for": [stamp["fingerprint"], stamp["module_sha256"]]})


def _failed_before(fingerprint: str | None) -> str | None:
    """Why the last build of these very sources failed, or None."""
    try:
        stamp = aot.read_stamp()
    except ValueError:
        return None
    if stamp is None or stamp.get("built") is not False or stamp.get("fingerprint") != fingerprint:
        return None
    return str(stamp.get("reason", "unknown"))


def build(verbose: bool = True, force: bool = False) -> bool:
    """Build the module and its stamp (unless they are current); True if built. A failure is
    recorded in the stamp."""
    fingerprint = aot.source_fingerprint()
    if not force and aot.stamp_problem() is None:  # the module of these sources is there
        _record_identities()
        return True
    failed = _failed_before(fingerprint)
    if not force and failed is not None:  # do not try again at every make (about 30 s each)
        print(f"ilcforce: ahead-of-time kernels not built ({failed}); commands run through numba. "
              "`python -m ilcforce.compiled.build --force` tries again", file=sys.stderr)
        return False
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numba.pycc's pending-deprecation notice
            from numba.pycc import CC
        exports = _exports()
        with tempfile.TemporaryDirectory(prefix="ilcforce-aot-") as tmp:
            cc = CC(aot.MODULE.rpartition(".")[2])
            cc.output_dir = tmp
            cc.verbose = False
            for name, signature, function in exports:
                cc.export(name, signature)(function)
            with warnings.catch_warnings(), _releasing_the_gil():
                warnings.simplefilter("ignore")
                cc.compile()
            built = list(Path(tmp).glob(aot.MODULE.rpartition(".")[2] + "*"))
            if len(built) != 1:
                raise RuntimeError(f"expected one extension module, found {[p.name for p in built]}")
            target = aot.module_path()
            if built[0].name != target.name:
                raise RuntimeError(f"built {built[0].name}, this Python loads {target.name}")
            # whole or not at all, also beside a concurrent build or a process that has it loaded
            fd, partial = tempfile.mkstemp(prefix=f".{target.name}.", dir=aot.PACKAGE)
            os.close(fd)
            try:
                shutil.copyfile(built[0], partial)
                os.chmod(partial, 0o755)
                digest = aot.file_digest(Path(partial))
                os.replace(partial, target)
            except BaseException:
                Path(partial).unlink(missing_ok=True)
                raise
    except Exception as exc:  # noqa: BLE001 - recorded; commands run through numba instead
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}".rstrip(": ")
        _write_stamp({"built": False, "reason": reason, "fingerprint": fingerprint})
        print(f"ilcforce: ahead-of-time kernels not built ({reason}); commands will run through numba "
              "(same numbers, a slower start)", file=sys.stderr)
        return False
    _write_stamp({"built": True, "fingerprint": fingerprint, "module_sha256": digest,
                  "exports": sorted(n for n, _, _ in exports)})
    _record_identities()
    if verbose:
        print(f"ilcforce: ahead-of-time kernels built ({len(exports)} exports, "
              f"{time.perf_counter() - t0:.0f} s): {target.name}")
    return True


if __name__ == "__main__":
    build(force="--force" in sys.argv[1:])
