"""The console entry point's first lines: stop signals answered from the first moment.

``ilcforce`` and ``python -m ilcforce`` call :func:`main` before importing anything else of the command.
Until the command's own handling starts (:func:`ilcforce.cli_main.main`, under
:func:`ilcforce.cli_signals.stop_signals`), Python is importing typer, the CLI and what the command
needs, and a Ctrl-C there raised KeyboardInterrupt in the middle of an import: a traceback. A stop
signal in that window now ends the process with the same one line and exit code as anywhere else
(``interrupted: ...``, 130; ``terminated (SIGTERM): ...``, 143). Not in ``ilcforce/__init__``:
a notebook or a test importing ilcforce keeps its own Ctrl-C.
"""

from __future__ import annotations

import os
import signal

from ilcforce.cli_signals import STOPS, announce, stop_code


def _stopped_while_starting(signum, frame) -> None:
    STOPS.append(signum)
    try:
        os.write(2, (announce("stopped before the command started") + "\n").encode())
    finally:
        os._exit(stop_code())


def main() -> None:
    """Run the command (:func:`ilcforce.cli_main.main`), stop signals answered from here on.

    Set here, not at import: a process that multiprocessing spawns (a Dask worker of a study)
    imports the console script again, but does not call ``main``."""
    for stop in (signal.SIGINT, signal.SIGTERM):
        signal.signal(stop, _stopped_while_starting)
    from ilcforce.cli import main as run

    run()
