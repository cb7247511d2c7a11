"""numba's start, made lighter for a process that only loads cached kernels. Import it before numba.

numba's CPU target is built for compiling. Before it loads a kernel from its on-disk cache it
"refreshes" the target: it imports and installs every lowering registry it has (builtins, arrays,
linalg, random, typed containers, ...), about 0.15-0.25 s of every cold ``ilcforce`` command on a
2-core machine, measured. Loading cached code needs none of it: a cached kernel is machine code
whose only run-time needs are numba's C helpers (installed with the target itself) and its
reference-counting runtime (NRT). So a cache load here starts NRT and loads; anything that compiles
(a cache miss, a new law) still refreshes the target first, as numba's compiler always does.

The stored numbers do not change: it is the same machine code, loaded the same way
(``tests/test_reference_run.py`` compares every dataset bit for bit). Anything unexpected in
numba's internals (another version's layout) leaves numba's own loading in place, only slower;
``tests/test_imports.py`` checks that the lighter path is the one taken here.
"""

from __future__ import annotations

import ilcforce._lapack  # noqa: F401, I001 - before numba: numba's LAPACK modules without all of scipy.linalg


def _lighter_cache_loads() -> bool:
    """Make ``numba.core.caching.Cache.load_overload`` skip the target's refresh; True if it does."""
    try:
        from numba.core import caching
        from numba.core.runtime import nrt
    except ImportError:
        return False
    cache = caching.Cache
    if getattr(cache.load_overload, "ilcforce_light", False):
        return True
    needed = ("_load_overload", "_guard_against_spurious_io_errors")
    if not all(hasattr(cache, name) for name in needed) or not hasattr(getattr(nrt, "rtsys", None), "initialize"):
        return False

    def load_overload(self, sig, target_context):
        """numba's own, without ``target_context.refresh()``: NRT started, then the cached code loaded."""
        nrt.rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)
        return None  # the guard swallowed a spurious I/O error: numba then compiles (and refreshes)

    load_overload.ilcforce_light = True  # type: ignore[attr-defined]
    cache.load_overload = load_overload
    return True


LIGHT_CACHE_LOADS = _lighter_cache_loads()
