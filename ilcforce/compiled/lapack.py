"""Load the two LAPACK/BLAS modules numba needs without importing all of ``scipy.linalg``.

numba reaches BLAS and LAPACK through ``scipy.linalg.cython_blas`` and ``scipy.linalg.cython_lapack``
(its ``np.linalg.solve`` and ``@`` call them): it checks for them when it compiles
(``numba.np.arraymath`` runs ``ensure_blas()`` at import), and a compiled solve imports
``cython_lapack`` the first time it runs (numba's C helper). Importing a submodule imports its
package first, and ``scipy.linalg/__init__`` imports the whole of scipy.linalg: about 170 ms of a
cold ``ilcforce simulate`` (measured with ``python -X importtime``), for two extension modules that
load in 9 ms on their own.

:func:`preload` loads those two extension modules from scipy's own files under their own names, so
numba finds them in ``sys.modules``; they are the same modules (same files, same function pointers),
so every number is unchanged. ``scipy.linalg`` itself still imports normally when some code asks for
it (e.g. ``scipy.signal`` for the PD-ILC filter). Anything unexpected (another scipy layout, the
modules already imported, an import error) leaves the normal import path in place.
"""

from __future__ import annotations

import sys

_MODULES = ("cython_blas", "cython_lapack")  # cython_lapack's init imports cython_blas: keep this order


def preload() -> None:
    """Put ``scipy.linalg.cython_blas`` / ``cython_lapack`` in ``sys.modules`` (no-op if there already)."""
    if "scipy.linalg" in sys.modules or all(f"scipy.linalg.{m}" in sys.modules for m in _MODULES):
        return
    try:
        import importlib.machinery
        import importlib.util
        from pathlib import Path

        import scipy

        folder = Path(scipy.__file__).parent / "linalg"
        for name in _MODULES:
            full = f"scipy.linalg.{name}"
            if full in sys.modules:
                continue
            spec = importlib.machinery.PathFinder.find_spec(name, [str(folder)])
            if spec is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader):
                return
            spec = importlib.util.spec_from_file_location(full, spec.origin)
            module = importlib.util.module_from_spec(spec)
            sys.modules[full] = module
            try:
                spec.loader.exec_module(module)
            except BaseException:
                del sys.modules[full]
                raise
    except Exception:  # noqa: BLE001 - numba's own import path still works, only slower
        return


preload()
