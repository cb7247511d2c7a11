"""The command line assembled (every command module registers on the app) and run: the command under the stop-signal
handling of :mod:`ilcforce.stops`, say in one line what typer would have drawn as a box or not
said at all, then end the process at once with the command's exit code."""

from __future__ import annotations

import os
import sys

import typer

from ilcforce.cli import analyze, config, report, run, study, tune  # noqa: F401 - each registers its commands on the app
from ilcforce.cli.base import _say, app
from ilcforce.stops import ANNOUNCED, STOPS, announce, stop_code, stop_signals


def main() -> None:
    """The console entry point: run the command, then end the process at once with its exit code.

    Python's normal exit tears down numba's compiled code and LLVM object by object: about 0.3 s of
    a 1.6 s cold `ilcforce simulate` (measured: the same run ends 0.24-0.44 s sooner with os._exit).
    Nothing is left to do by then (every store is closed, every worker process joined or its
    cluster closed, inside the command), so after flushing stdout and stderr the process exits with
    ``os._exit``. An unexpected exception still goes the normal way, with its traceback.
    """
    try:
        with stop_signals():
            # not standalone: a usage error (an unknown option, a bad value for an option) comes here
            # to be said in one line, instead of typer's framed box of four or more
            result = app(standalone_mode=False)
        code = result if isinstance(result, int) else 0
    except typer.Abort:  # end of input at a prompt (ilcforce has none)
        code = 1
    except Exception as exc:
        # click's ClickException (typer vendors click from 0.2x on: matched by what it offers)
        if not (hasattr(exc, "format_message") and isinstance(getattr(exc, "exit_code", None), int)):
            raise
        message = " ".join(exc.format_message().split())
        if message:  # none when typer has just printed the help (no command given)
            where = f" (see `{exc.ctx.command_path} --help`)" if getattr(exc, "ctx", None) is not None else ""
            _say(f"error: {message}{where}", stderr=True)
        code = exc.exit_code
    except SystemExit as exc:  # a command ended with one outside typer's handling
        if exc.code is None or isinstance(exc.code, int):
            code = exc.code or 0
        else:  # a message: print it as sys.exit would
            print(exc.code, file=sys.stderr)
            code = 1
    except KeyboardInterrupt:  # a stop signal outside typer's own handling
        code = 130
    if STOPS and not ANNOUNCED and code in (0, 130):
        # the signal landed outside a command's own handling (while typer parsed the arguments or
        # a command imported what it needs: typer turns that into a silent exit 130), or Python
        # dropped its KeyboardInterrupt and the command finished. A command that failed with its
        # own line (exit 2) has said what matters.
        _say(announce("stopped before the command finished" if code else "the command had finished"), stderr=True)
        code = stop_code()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken pipe: nothing more can be said
            pass
    os._exit(code)

