"""The console entry point's first lines: stop signals answered from the first moment.

``ilcforce`` and ``python -m ilcforce`` call :func:`main` before importing anything else of the command.
Until the command's own handling starts (:func:`ilcforce.cli.main.main`, under
:func:`ilcforce.stops.stop_signals`), Python is importing typer, the CLI and what the command
needs, and a Ctrl-C there raised KeyboardInterrupt in the middle of an import: a traceback. A stop
signal in that window now ends the process with the same one line and exit code as anywhere else
(``interrupted: ...``, 130; ``terminated (SIGTERM): ...``, 143). Not in ``ilcforce/__init__``:
a notebook or a test importing ilcforce keeps its own Ctrl-C.
"""

from __future__ import annotations

import os
import sys

from ilcforce import stops

#: How often (s) the interpreter hands the GIL to a waiting thread (Python's default: 5 ms). A run's
#: threads (the compiled loop, the next iterations' noise draws, the store's writes) each hold it
#: briefly; at 5 ms the simulation thread waited up to 5 ms at every hand-over.
SWITCH_INTERVAL = 1e-4


def one_blas_thread() -> None:
    """OpenBLAS (numpy's, and scipy's for the compiled solves) without worker threads, unless the
    user chose a number (``OPENBLAS_NUM_THREADS``): every matrix ilcforce multiplies is 2 x 2, so
    the workers never share the work, but each library starts one per extra core at import and it
    spins for about 0.1 s before sleeping. Measured on 2 cores: 0.2-0.3 s of CPU of a 0.8 s cold
    `simulate`, competing with the simulation for the second core. Set before numpy is
    imported; inherited by the processes a command starts (compare's workers, a study's cluster)."""
    if not os.environ.get("OPENBLAS_NUM_THREADS", "").strip():
        os.environ["OPENBLAS_NUM_THREADS"] = "1"


def main() -> None:
    """Run the command (:func:`ilcforce.cli.main.main`), stop signals answered from here on.

    Set here, not at import: a process that multiprocessing spawns (a Dask worker of a study)
    imports the console script again, but does not call ``main``."""
    stops.answer_from_the_start()
    one_blas_thread()
    sys.setswitchinterval(SWITCH_INTERVAL)
    # a closed stdout or stderr (`ilcforce ... >&-`): Python has None there; what would be printed
    # goes nowhere, as to a closed terminal, instead of an AttributeError at the first line
    for name in ("stdout", "stderr"):
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, "w"))  # noqa: SIM115 - lives as long as the process
    from ilcforce.cli.main import main as run

    run()
