"""What every command of the command line uses: the Typer app, the output consoles, the one-line errors,
the configuration loader and the table drawer. Imports no command (they import it).

Exit codes: 0 success (a diverged method is a result, not a failure), 2 bad input or a store that
cannot be used (one line on stderr, never a traceback), 130 interrupted (Ctrl-C), 143 terminated
(SIGTERM, which takes Ctrl-C's path: :mod:`ilcforce.stops`).
"""

from __future__ import annotations

import functools
import os
import math
import shlex
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce import __version__
from ilcforce.stops import announce, stop_code
from ilcforce.controllers import PAPER_METHODS, REGISTRY

# Only what every command needs is imported here: `ilcforce --help` and one-line input errors must
# not pay for rich's consoles and tables, pandas, numba's kernels, h5py or matplotlib
# (`python -X importtime -m ilcforce --help` shows what is left). Commands import what they use.


class _LazyConsole:
    """A rich ``Console`` made on first use; ``out.print(...)`` and ``err.print(...)`` as usual."""

    def __init__(self, stderr: bool) -> None:
        self._stderr = stderr
        self._console = None

    def console(self):
        """The rich ``Console`` itself (for rich objects that take one)."""
        if self._console is None:
            from rich.console import Console

            self._console = Console(stderr=self._stderr)
        return self._console

    def __getattr__(self, name: str):
        return getattr(self.console(), name)

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Iterative learning control for hybrid force/position control of robot manipulators in contact "
         "(a five-bar, a serial 2R arm, arms read from a URDF or MJCF model file); reproduces and checks the "
         "ILC + sliding mode paper. `ilcforce COMMAND --help` describes a command and its options; "
         "`ilcforce config` prints every setting with its value, as an experiment file.",
)
out = _LazyConsole(stderr=False)
err = _LazyConsole(stderr=True)


class CliError(Exception):
    """Bad input found by the CLI itself."""


def _say(text: str, *, stderr: bool = False) -> None:
    """One plain line: never markup, never wrapped, never a UnicodeEncodeError (unencodable
    characters are replaced under an ASCII locale)."""
    stream = sys.stderr if stderr else sys.stdout
    encoding = getattr(stream, "encoding", None) or "utf-8"
    line = " ".join(str(text).split()) if "\n" in str(text) else str(text)
    try:
        stream.write(line.encode(encoding, "replace").decode(encoding, "replace") + "\n")
        stream.flush()
    except (OSError, ValueError):
        pass


def _fail(message: str, code: int = 2) -> None:
    _say(f"error: {message}", stderr=True)
    raise typer.Exit(code)


#: What each command says after "interrupted: " or "terminated (SIGTERM): " when a stop signal ends it.
_ON_STOP = {"simulate": "every finished iteration is stored; continue with --resume",
            "compare": "every finished iteration is stored; run the same command to continue",
            "report": "the report was not finished; run `ilcforce report` again",
            "validate": "nothing was changed"}


def _guard(func):
    """Turn the library's input errors into one line and exit code 2, and a stop signal (Ctrl-C,
    SIGTERM) into one line and exit code 130 or 143."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            from ilcforce.config import ConfigError
            from ilcforce.controllers.nd import LawError
            from ilcforce.experiment import UnknownMethodError
            from ilcforce.store import StoreError

            try:
                return func(*args, **kwargs)
            except (ConfigError, StoreError, UnknownMethodError, CliError, LawError) as exc:
                _fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            except OSError as exc:
                _fail(f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": "))
            except MemoryError as exc:  # numpy's says what it could not allocate
                _fail(f"out of memory: {exc}".rstrip(": ") + " (every finished iteration is stored)"
                      if func.__name__ in ("simulate", "compare") else f"out of memory: {exc}".rstrip(": "))
        except KeyboardInterrupt:
            _say(announce(_ON_STOP.get(func.__name__, "stopped")), stderr=True)
            raise typer.Exit(stop_code())

    return wrapper


def _load(config: Optional[Path], seed: Optional[int], iters: Optional[int], sets: Optional[list[str]]):
    from ilcforce.compiled.note import announce_compiles

    # a first run compiles before iteration 0 (minutes without the ahead-of-time kernels): say so on
    # stderr, terminal or not, so that a piped or logged first run does not look hung
    announce_compiles(lambda text: _say(text, stderr=True))
    from ilcforce.config_load import command_overrides, load_config

    return load_config(config, command_overrides(sets, seed, iters))


def _variant(seed: Optional[int], sets: Optional[list[str]]) -> dict[str, object]:
    """The overrides that make a variant (its own results folder): every --set, and --seed."""
    from ilcforce.config_load import command_overrides

    return command_overrides(sets, seed)


def _methods(text: str) -> list[str]:
    """The registry's names of a comma-separated list (any case: the registry's one rule)."""
    from ilcforce.controllers import MethodNameError, canonical_method

    names = [m for m in text.split(",") if m.strip()]
    if not names:
        raise CliError("--methods is empty; e.g. --methods c1,c2,c3")
    try:
        return [canonical_method(name) for name in names]
    except MethodNameError as exc:
        raise CliError(str(exc)) from None


def _g(value) -> str:
    """A table cell: 3 significant digits, '-' for a missing value (None, NaN, pandas NA)."""
    if value is None or type(value).__name__ == "NAType":  # pandas.NA, without importing pandas
        return "-"
    if isinstance(value, float):
        return "-" if math.isnan(value) else f"{value:.3g}"
    return str(value)


def _command_line(ctx: typer.Context) -> str:
    """The invocation as ilcforce saw it (resolved options), for the store's provenance."""
    parts = ["ilcforce", ctx.info_name or ""]
    flags = {"out_path": "--out", "out_dir": "--out", "sets": "--set"}
    positional = {p.name for p in ctx.command.params if p.param_type_name == "argument"}
    for name, value in ctx.params.items():
        if value in (None, False, [], ()):
            continue
        flag = flags.get(name, "--" + name.replace("_", "-"))
        values = value if isinstance(value, (list, tuple)) else [value]
        for v in values:
            parts += [str(v)] if name in positional else [flag] if v is True else [flag, str(v)]
    return shlex.join(parts)


def table(title: str, console=None):
    """A rich Table whose title is shown literally (a path may contain [brackets]); ASCII borders
    when the output encoding cannot show box-drawing characters. No cell ever wraps: a number is
    never split across lines (a table wider than the output is the caller's to split)."""
    from rich import box
    from rich.table import Table
    from rich.text import Text

    console = console or out.console()
    encoding = (console.encoding or "").lower().replace("-", "")
    return Table(title=Text(title), box=box.HEAVY_HEAD if encoding.startswith("utf") else box.ASCII2,
                 title_justify="left")


def fits(console) -> int:
    """The width a table may take on ``console``: the terminal's, or 80 columns for a pipe or a file
    (a log read later is read in an ordinary window)."""
    return console.width if console.is_terminal else 80



def show(grid, console=None) -> None:
    """Print a table from :func:`table`: at its natural width off a terminal (a pipe or a log file
    has no width to keep to), within the terminal's otherwise; characters the output's encoding
    cannot show are replaced, never a UnicodeEncodeError."""
    from rich.measure import Measurement

    console = console or out.console()
    if not console.is_terminal:  # rich keeps to the console's width (80 off a terminal): one as wide as the table
        from rich.console import Console

        width = Measurement.get(console, console.options.update_width(10_000), grid).maximum
        console = Console(width=max(width, console.width), color_system=None, force_terminal=False,
                          legacy_windows=False)
    with console.capture() as captured:
        console.print(grid, crop=False)
    stream = sys.stdout
    encoding = getattr(stream, "encoding", None) or "utf-8"
    try:
        stream.write(captured.get().encode(encoding, "replace").decode(encoding, "replace"))
        stream.flush()
    except (OSError, ValueError):  # a closed or broken pipe: nothing more can be said
        pass
