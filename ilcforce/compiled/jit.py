"""numba, imported only when a kernel runs through it: the decorators of every kernel module.

A process that runs the ahead-of-time compiled kernels (:mod:`ilcforce.compiled.aot`) never imports numba,
which is about a third of a cold ``ilcforce simulate`` (numba's import and its cache loads). So
the kernel modules do not import numba themselves: they decorate with :func:`njit` and
:func:`intrinsic` from here and name numba's own globals (``carray``) with :func:`numba_global`,
and build numba types only inside functions (:class:`Sig`).

Until numba is needed these return placeholders. The first time a placeholder is called from
Python (or :func:`numba` is asked for, e.g. to compile a law), numba is imported, every
placeholder made so far becomes numba's real object (the same ``numba.njit(...)`` the module
would have made), and every module global that held a placeholder is rebound to it, so kernels
that call each other find real dispatchers when numba compiles or loads them. From then on the
decorators here are numba's own. The kernels, their numba options and numba's on-disk cache are
exactly those of a module that imported numba at the top; only when numba is imported changes.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable

_numba = None
_lock = threading.RLock()
_pending: list = []  # placeholders made before numba was imported, in the order they were made
_on_load: list[Callable[[object], None]] = []


class Sig:
    """A kernel signature built only when numba is imported: ``Sig(lambda: types.f8(types.f8))``."""

    def __init__(self, build: Callable[[], object]) -> None:
        self.build = build


def _resolve(args: tuple) -> tuple:
    return tuple(a.build() if isinstance(a, Sig) else a for a in args)


class _Placeholder:
    """A numba object not made yet; :attr:`real` makes it (importing numba first)."""

    _made = None

    @property
    def real(self):
        if self._made is None:
            nb = numba()
            if self._made is None:  # numba's import went on after another placeholder failed to be made
                self._make(nb)
        return self._made

    def _make(self, nb) -> None:
        raise NotImplementedError


class LazyKernel(_Placeholder):
    """``njit(*args, **options)(py_func)``, made when numba is imported."""

    def __init__(self, py_func: Callable, args: tuple, options: dict) -> None:
        self.py_func = py_func
        self._args = args
        self._options = options
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__module__ = py_func.__module__
        self.__doc__ = py_func.__doc__

    def _make(self, nb) -> None:
        self._made = nb.njit(*_resolve(self._args), **self._options)(self.py_func)

    def __call__(self, *args, **kwargs):
        return self.real(*args, **kwargs)

    def __getattr__(self, name: str):  # dispatcher attributes (signatures, overloads, ...)
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.real, name)

    def __repr__(self) -> str:
        return f"<ilcforce kernel {self.__qualname__} (numba not imported yet)>"

    def __reduce__(self):  # by reference, as a function or a numba dispatcher is
        return _module_attribute, (self.__module__, self.__qualname__)


def _module_attribute(module: str, qualname: str):
    import importlib

    found = importlib.import_module(module)
    for part in qualname.split("."):
        found = getattr(found, part)
    return found


class LazyIntrinsic(_Placeholder):
    """``numba.extending.intrinsic(fn)``, made when numba is imported."""

    def __init__(self, fn: Callable) -> None:
        self.fn = fn

    def _make(self, nb) -> None:
        from numba.extending import intrinsic as real_intrinsic

        self._made = real_intrinsic(self.fn)


class LazyGlobal(_Placeholder):
    """``getattr(numba, name)`` for a kernel's global (e.g. ``carray``)."""

    def __init__(self, name: str) -> None:
        self.name = name

    def _make(self, nb) -> None:
        self._made = getattr(nb, self.name)


def njit(*args, **options):
    """``numba.njit`` with the same call forms (``@njit``, ``@njit(sig, cache=True, ...)``);
    signatures given as :class:`Sig`."""
    if _numba is not None:
        return _numba.njit(*_resolve(args), **options)
    if len(args) == 1 and callable(args[0]) and not isinstance(args[0], Sig) and not options:
        return _remember(LazyKernel(args[0], (), {}))

    def decorate(py_func: Callable):
        if _numba is not None:
            return _numba.njit(*_resolve(args), **options)(py_func)
        return _remember(LazyKernel(py_func, args, options))
    return decorate


def intrinsic(fn: Callable):
    """``numba.extending.intrinsic``."""
    if _numba is not None:
        from numba.extending import intrinsic as real_intrinsic

        return real_intrinsic(fn)
    return _remember(LazyIntrinsic(fn))


def numba_global(name: str):
    """numba's ``name`` (e.g. ``"carray"``) as a kernel module's global."""
    if _numba is not None:
        return getattr(_numba, name)
    return _remember(LazyGlobal(name))


def _remember(placeholder: _Placeholder):
    with _lock:
        if _numba is not None:  # numba arrived meanwhile (another thread)
            placeholder._make(_numba)
            return placeholder._made
        _pending.append(placeholder)
    return placeholder


def loaded() -> bool:
    """True once numba is imported through here."""
    return _numba is not None


def on_load(callback: Callable[[object], None]) -> None:
    """``callback(numba)`` once numba is imported (at once if it is already)."""
    with _lock:
        if _numba is None:
            _on_load.append(callback)
            return
    callback(_numba)


def numba():
    """Import numba, make every placeholder real and rebind the module
    globals that hold them; return the numba module."""
    global _numba
    with _lock:
        if _numba is not None:
            return _numba
        _key_the_cache()
        import ilcforce.compiled.lapack  # noqa: F401 - before numba: its LAPACK modules without all of scipy.linalg
        import numba as nb

        if os.environ.get("NUMBA_CACHE_DIR") and nb.config.CACHE_DIR != os.environ["NUMBA_CACHE_DIR"]:
            nb.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]  # numba was imported before, by someone else

        _numba = nb  # from here on the decorators are numba's own
        for callback in _on_load:
            callback(nb)
        # a kernel with an explicit signature compiles (or loads) when made, so every kernel it
        # calls must already be real and bound where it looks it up: make the others first
        eager = [p for p in _pending if isinstance(p, LazyKernel) and p._args]
        for group in ([p for p in _pending if p not in eager], eager):
            for placeholder in group:
                placeholder._make(nb)
            _rebind()
        _pending.clear()
    return nb


def _key_the_cache() -> None:
    """numba's on-disk cache (``NUMBA_CACHE_DIR``) in a folder named after the kernels' sources.

    numba finds a cached kernel stale only when the kernel's own file changed, not when a kernel
    it calls did (an edit of ``joint_torque`` in ``controllers/base.py`` left every law's cached
    code as it was, and the ahead-of-time build, which compiles through the same cache, compiled
    the old code). A folder per fingerprint of every kernel source (:data:`ilcforce.compiled.sources.SOURCES`)
    makes any such edit start from an empty cache. Without ``NUMBA_CACHE_DIR`` numba keeps its
    cache beside the sources, as it does by default.
    """
    from pathlib import Path

    from ilcforce.compiled.sources import source_fingerprint

    base = os.environ.get("NUMBA_CACHE_DIR")
    fingerprint = source_fingerprint()
    if not base or fingerprint is None or Path(base).name.startswith(_CACHE_PREFIX):  # keyed already (a child)
        return
    os.environ["NUMBA_CACHE_DIR"] = str(Path(base) / f"{_CACHE_PREFIX}{fingerprint[:16]}")


_CACHE_PREFIX = "ilcforce-sources-"


def _rebind() -> None:
    """Replace every made placeholder held as a module global by its real object."""
    made = {id(p): p._made for p in _pending if p._made is not None}
    kinds = (LazyKernel, LazyIntrinsic, LazyGlobal)
    for module in list(sys.modules.values()):
        try:
            namespace = object.__getattribute__(module, "__dict__")
        except (AttributeError, TypeError):
            continue
        if not isinstance(namespace, dict):
            continue
        for name, value in list(namespace.items()):
            if type(value) in kinds and id(value) in made:  # type(), not isinstance: a proxy's __class__ may raise
                namespace[name] = made[id(value)]


def python_calls(plant_cls: type, numba_kernels: Callable[[], tuple], kind: type):
    """A plant's kernels as Python calls them: the ahead-of-time compiled ones when they are built
    (:mod:`ilcforce.compiled.aot`; numba is then never imported), else ``numba_kernels()``. The same
    machine code either way. Plants ask here, so that none of them imports the loader."""
    from ilcforce.compiled import aot

    return aot.plant_kernels(plant_cls, kind) or numba_kernels()
