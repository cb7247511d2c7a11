"""``ilcforce simulate`` begun before its command line is parsed: the compiled loop runs while typer loads.

A cold ``simulate`` spent about 50 ms importing typer, click and the CLI and parsing the arguments
before iteration 0 could start (issue 12). :func:`begin`, called by ``ilcforce._entry.main`` before
the CLI is imported, reads a plain ``simulate`` command line itself: only the options below, each
as ``--option value`` or ``--option=value``; anything else (``--resume``, ``--help``, an unknown
option, a value that starts with ``-``) and nothing begins early. It builds the configuration as
the command does and starts the iterations in a background thread (:func:`ilcforce.experiment.
start_iterations`); it opens no store and writes no file.

The command, once typer has parsed the arguments, asks :func:`take` for the run: it gets it only
when the run was started for the same method and a configuration whose TOML (what the store keeps)
is the same; otherwise the early run is stopped and the command starts its own. Whatever the early
reading gets wrong therefore costs time, never a number: the records are those of the same
function with the same inputs. Only the ahead-of-time compiled kernels run early (a first run
through numba announces its compiles first; :mod:`ilcforce.compiled.note`).
"""

from __future__ import annotations

import threading

#: option -> (name, kind) for the options read here; kind "flag" takes no value
OPTIONS = {
    "--method": ("method", "text"), "-m": ("method", "text"),
    "--iters": ("iters", "int"), "-n": ("iters", "int"),
    "--seed": ("seed", "int"),
    "--config": ("config", "text"), "-c": ("config", "text"),
    "--set": ("sets", "list"),
    "--out": ("out", "text"), "-o": ("out", "text"),
    "--results": ("results", "text"),
    "--overwrite": ("overwrite", "flag"),
}

_lock = threading.Lock()
_started = None  # the StartedRun begun by begin(), until take() hands it over or drops it


def read_arguments(args: list[str]) -> dict | None:
    """The options of a plain ``simulate`` command line, or None if it is not one (see the module)."""
    if not args or args[0] != "simulate":
        return None
    found: dict = {"method": "c3", "sets": []}
    rest = list(args[1:])
    while rest:
        token = rest.pop(0)
        option, eq, value = token.partition("=")
        if option not in OPTIONS or (eq and not option.startswith("--")):
            return None
        name, kind = OPTIONS[option]
        if kind == "flag":
            if eq:
                return None
            found[name] = True
            continue
        if not eq:
            if not rest:
                return None
            value = rest.pop(0)
        if not value or value.startswith("-"):
            return None
        if kind == "int":
            if not value.isdigit():
                return None
            found[name] = int(value)
        elif kind == "list":
            found[name].append(value)
        else:
            found[name] = value  # given twice, the last counts (as for the parser)
    return found


def _config(found: dict):
    """The configuration ``ilcforce simulate`` builds from these options (as ``ilcforce.cli._load``)."""
    from ilcforce.config_load import command_overrides, load_config

    return load_config(found.get("config"), command_overrides(found["sets"], found.get("seed"), found.get("iters")))


def _compiled(config, method: str) -> bool:
    """Whether the run would use only ahead-of-time compiled kernels (no numba compile to announce)."""
    from ilcforce.compiled import aot
    from ilcforce.experiment import make_controller
    from ilcforce.plants import make_plant

    if aot.module() is None:
        return False
    controller = make_controller(config, method)
    true_cls = type(make_plant(config.plant.true_plant(0)))
    nominal_cls = type(make_plant(config.plant.links()))
    # (aot.desired would load LAPACK here, before iteration 0: the run's inputs thread does that)
    return (aot.simulator(controller, true_cls, nominal_cls) is not None
            and hasattr(aot.module(), f"desired__{aot.plant_key(true_cls)}"))


def begin(args: list[str]) -> bool:
    """Start the iterations of the ``simulate`` command line ``args`` (``sys.argv[1:]``), if it is a
    plain one whose configuration loads; True if they started. Never raises: whatever is wrong with
    the command line is the command's to say."""
    global _started
    try:
        found = read_arguments(args)
        if found is None:
            return False
        method = found["method"].strip().lower()
        config = _config(found)
        if not _compiled(config, method):
            return False
        from ilcforce.experiment import start_iterations

        run = start_iterations(config, method)
    except Exception:  # noqa: BLE001 - the command will meet the same fault and say it in one line
        return False
    with _lock:
        _started = run
    return True


def wait_running(timeout: float = 0.5) -> None:
    """Wait (at most ``timeout`` s) until the early run's compiled loop runs and what iteration 0's
    end needs is made: the imports that follow would otherwise share the GIL with that work."""
    run = _started
    if run is not None:
        run.turns.wait_ready(timeout)


def _pop():
    """The early run, no longer the module's (None if there is none)."""
    global _started
    with _lock:
        run, _started = _started, None
    return run


def take(config, method: str, *, resume: bool = False):
    """The early run if it was started for ``method`` with this configuration (and the command does
    not resume); else None, the early run (if any) stopped. Only the first call can get it."""
    run = _pop()
    if run is not None and (resume or not run.is_for(config, method)):
        run.close()
        return None
    return run


def drop() -> None:
    """Stop the early run, if one is waiting (e.g. for a command that will not take it)."""
    run = _pop()
    if run is not None:
        run.close()
