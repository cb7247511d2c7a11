"""One line on the terminal when numba compiles, so that a first run does not look hung.

After an install or a change to the simulation code, numba compiles the kernels before the first
iteration can start (10 s for C3 on the five-bar on a 2-core machine, measured; more when several
methods compile), with the progress display still at 0.
Later runs load them from numba's on-disk cache (``NUMBA_CACHE_DIR``) in a fraction of a second
and say nothing. numba announces each compile as a ``numba:compile`` event (a cache load is not
one); the first such event in this process prints the note, once.
"""

from __future__ import annotations

from collections.abc import Callable

from ilcforce.compiled import jit as _jit

NOTE = ("compiling the simulation kernels (only the first run after an install or a code change; "
        "later runs load them from numba's cache)")

_asked: list = []  # announce_compiles was called (once is enough)
_installed: list = []  # the listener registered with numba, once numba is imported


def announce_compiles(say: Callable[[str], None]) -> None:
    """From now on, ``say(NOTE)`` at the first compile numba starts in this process (once). numba
    is not imported for it: the listener is installed when numba is (ahead-of-time kernels,
    :mod:`ilcforce.compiled.aot`, need no numba and compile nothing)."""
    if _asked:
        return
    _asked.append(say)
    _jit.on_load(lambda numba: _listen(say))


def _listen(say: Callable[[str], None]) -> None:
    from numba.core import event

    class _FirstCompile(event.Listener):
        said = False

        def on_start(self, ev) -> None:
            if not self.said:
                self.said = True
                say(NOTE)

        def on_end(self, ev) -> None:
            pass

    listener = _FirstCompile()
    event.register("numba:compile", listener)
    _installed.append(listener)
