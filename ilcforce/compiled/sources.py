"""Which files the compiled kernels are made from, and one fingerprint of them.

The ahead-of-time module (:mod:`ilcforce.compiled.aot`) is retired, and numba's on-disk cache
starts afresh (:mod:`ilcforce.compiled.jit`), when any of these files changes: numba alone only
notices a change to a kernel's own file, not to a kernel it calls.
"""

from __future__ import annotations

import functools
from pathlib import Path

#: the package folder (``ilcforce/``)
PACKAGE = Path(__file__).resolve().parent.parent
#: every file whose code the extension module holds (a change to any of them retires it)
SOURCES = ("compiled/jit.py", "compiled/build.py", "compiled/dense.py", "compiled/views.py", "loop.py", "ndof/*.py",
           "task.py", "controllers/*.py", "plants/*.py")


def source_files() -> list[Path]:
    """The regular, visible files of :data:`SOURCES` (an editor's ``.#c3.py`` lock link is not one)."""
    found = []
    for pattern in SOURCES:
        for path in sorted(PACKAGE.glob(pattern)):
            if not path.name.startswith(".") and not path.is_symlink() and path.is_file():
                found.append(path)
    return found


@functools.cache
def source_fingerprint() -> str | None:
    """sha256 over the names and bytes of :data:`SOURCES`; None if one cannot be read."""
    import hashlib  # here, not at the top: a command whose stamp's file identities match needs none

    digest = hashlib.sha256()
    try:
        for path in source_files():
            digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0")
            digest.update(path.read_bytes())
    except OSError:
        return None
    return digest.hexdigest()


