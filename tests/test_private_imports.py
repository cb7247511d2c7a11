"""ilcforce holds its dependencies by their public APIs only, or by a private part written down here,
each with the upper bound pinned in pyproject.toml and the reason it is used.

The scan (the ``ast`` of every module under ilcforce/) finds, for dask, distributed, multiprocessing,
numba and llvmlite:

* a ``_``-prefixed module or attribute, imported or used (``from dask._task_spec import Task``,
  ``numba._helperlib``, ``getattr(numba, "_x")``) or a ``_``-prefixed keyword passed to one of
  their callables (``Task(..., _data_producer=True)``);
* a patch: an attribute of one of their modules or classes assigned or deleted
  (``multiprocessing.util.spawnv_passfds = f``; setting an attribute of an object one made is no patch);
* a deprecated module (numba.pycc).

Names are followed through ``import ... as``, ``from ... import``, plain assignments and calls, and
through ``ilcforce.compiled.jit.numba()`` (which returns the numba module). A use not in
:data:`ALLOWED` fails with one line naming the file and the name; so does an entry no longer used,
an entry whose bound is not the one pinned, and an entry whose private part the installed package
no longer has (a new release moved it: the pin is what keeps a fresh install working).
"""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from ilcforce.study.dask_run import DASK_REQUIREMENT as DASK  # the line a Dask without the flag gives names it

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ilcforce"
PACKAGES = ("dask", "distributed", "multiprocessing", "numba", "llvmlite")
#: modules their makers have deprecated: held like a private part
DEPRECATED = ("numba.pycc",)

NUMBA = "numba>=0.59,<0.69"


def _data_producer_task() -> str | None:
    from dask._task_spec import Task, parse_input

    task = Task("probe", max, parse_input(1), parse_input(2), _data_producer=True)
    if task.data_producer is not True:
        return "Task(..., _data_producer=True).data_producer is not True"
    import inspect

    from distributed.scheduler import SchedulerState

    if "data_producer" not in inspect.getsource(SchedulerState.is_rootish):
        return "the scheduler's is_rootish no longer reads the task's data_producer flag"
    return None


def _pycc_flags() -> str | None:
    import inspect
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from numba.pycc import CC, compiler  # noqa: F401

    if not hasattr(compiler.Flags(), "release_gil"):
        return "numba.pycc.compiler.Flags() has no release_gil"
    if "Flags()" not in inspect.getsource(compiler):
        return "numba.pycc's compiler no longer takes its flags from Flags()"
    return None


def _numba_cache_dir() -> str | None:
    import numba

    return None if isinstance(getattr(numba.config, "CACHE_DIR", None), str) else "numba.config.CACHE_DIR is gone"


@dataclass(frozen=True)
class Allowed:
    bound: str  # the requirement pinned in pyproject.toml, with its upper bound
    reason: str
    probe: Callable[[], str | None]  # None while the installed package still has the private part


#: (file, name) -> why it is used and the bound that keeps it working. The one list.
ALLOWED: dict[tuple[str, str], Allowed] = {
    **{("ilcforce/study/dask_run.py", name): Allowed(
        DASK,
        "Dask has no public way to mark a task for the scheduler's queue: a Task marked as a data "
        "producer is queued by the scheduler and handed to a worker only when one of its threads is "
        "free (worker-saturation 1.0), so a cell that kills its worker takes no waiting cell with it, "
        "no cell is pinned to a worker, and a freed worker starts its next cell without waiting for "
        "the driver (client.submit's tasks go to a worker at once unless their group outnumbers the "
        "cluster's threads twice over; priority and fifo change the order, not where a task waits). "
        "docs/design.md, 'Why Dask'.",
        _data_producer_task)
       for name in ("dask._task_spec.Task", "dask._task_spec.parse_input", "dask._task_spec.Task(_data_producer=)")},
    **{("ilcforce/compiled/build.py", name): Allowed(
        NUMBA,
        "numba.pycc is numba's only ahead-of-time compiler (deprecated; the plan for its removal is in "
        "docs/design.md, 'Why numba'); it has no option for nogil, so the build sets release_gil in "
        "the Flags its compiler makes, as numba's nogil=True does.",
        _pycc_flags)
       for name in ("numba.pycc.CC", "numba.pycc.compiler", "numba.pycc.compiler.Flags")},
    ("ilcforce/compiled/jit.py", "numba.config.CACHE_DIR"): Allowed(
        NUMBA,
        "numba reads NUMBA_CACHE_DIR once, when it is imported; when something imported numba before "
        "ilcforce keyed the cache by the kernels' sources, the folder is set where numba reads it.",
        _numba_cache_dir),
}


def _private(part: str) -> bool:
    return part.startswith("_") and not (part.startswith("__") and part.endswith("__"))


class _Scan(ast.NodeVisitor):
    """The uses in one module: (line, kind, name), kind being private, patch or deprecated."""

    def __init__(self) -> None:
        self.bound: dict[str, str] = {}  # local name -> the dotted name of theirs it holds
        self.found: list[tuple[int, str, str]] = []

    def _note(self, node: ast.AST, name: str, kind: str | None = None) -> None:
        if kind is None:
            if any(_private(part) for part in name.replace("(", ".").split(".")):
                kind = "private"
            elif any(name == d or name.startswith(d + ".") for d in DEPRECATED):
                kind = "deprecated"
            else:
                return
        self.found.append((node.lineno, kind, name))

    def resolve(self, node: ast.AST) -> str | None:
        if isinstance(node, ast.Name):
            return self.bound.get(node.id)
        if isinstance(node, ast.Attribute):
            base = self.resolve(node.value)
            return f"{base}.{node.attr}" if base else None
        if isinstance(node, ast.Call):
            func = self.resolve(node.func)
            if func:
                return func + "()"
            name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", None)
            return "numba" if name == "numba" else None  # ilcforce.compiled.jit.numba() returns the module
        return None

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            if alias.name.split(".")[0] in PACKAGES:
                self._note(node, alias.name)
                if alias.asname:
                    self.bound[alias.asname] = alias.name
                else:
                    top = alias.name.split(".")[0]
                    self.bound[top] = top

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.level or not node.module or node.module.split(".")[0] not in PACKAGES:
            return
        for alias in node.names:
            name = f"{node.module}.{alias.name}"
            self._note(node, name)
            self.bound[alias.asname or alias.name] = name

    def visit_Assign(self, node: ast.Assign) -> None:
        self.generic_visit(node)
        held = self.resolve(node.value)
        for target in node.targets:
            if isinstance(target, ast.Name):
                if held:
                    self.bound[target.id] = held
                else:
                    self.bound.pop(target.id, None)

    def visit_Attribute(self, node: ast.Attribute) -> None:
        base = self.resolve(node.value)
        if base:
            name = f"{base}.{node.attr}"
            if isinstance(node.ctx, (ast.Store, ast.Del)):
                if "()" not in base:  # a module's or a class's attribute, not an object's own
                    self._note(node, name, "patch")
            elif _private(node.attr):
                self._note(node, name, "private")
        self.generic_visit(node)

    def visit_Call(self, node: ast.Call) -> None:
        func = self.resolve(node.func)
        if func:
            for keyword in node.keywords:
                if keyword.arg and _private(keyword.arg):
                    self._note(node, f"{func}({keyword.arg}=)", "private")
        name = getattr(node.func, "id", None)
        if name in ("getattr", "setattr", "delattr") and len(node.args) >= 2:
            base = self.resolve(node.args[0])
            attr = node.args[1]
            if base and isinstance(attr, ast.Constant) and isinstance(attr.value, str):
                if name != "getattr":
                    if "()" not in base:
                        self._note(node, f"{base}.{attr.value}", "patch")
                elif _private(attr.value):
                    self._note(node, f"{base}.{attr.value}", "private")
        self.generic_visit(node)


def scan_source(text: str) -> list[tuple[int, str, str]]:
    scan = _Scan()
    scan.visit(ast.parse(text))
    return sorted(set(scan.found))


def scan() -> dict[tuple[str, str], tuple[int, str]]:
    """(file, name) -> (first line, kind) for every module under ilcforce/."""
    uses: dict[tuple[str, str], tuple[int, str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for line, kind, name in scan_source(path.read_text(encoding="utf-8")):
            uses.setdefault((path.relative_to(ROOT).as_posix(), name), (line, kind))
    return uses


def test_the_scan_finds_each_kind_of_use():
    """The check can fail: each form it looks for is found, and a public use is not."""
    source = (
        "import numba as nb\n"
        "from dask._task_spec import Task\n"
        "from multiprocessing import util\n"
        "import multiprocessing\n"
        "from numba.pycc import CC\n"
        "from ilcforce.compiled import jit as _jit\n"
        "def f(key, function):\n"
        "    util.spawnv_passfds = function\n"
        "    multiprocessing.util._exit_function()\n"
        "    types = _jit.numba().types\n"
        "    nb.core._helper\n"
        "    getattr(nb, '_private_thing')\n"
        "    setattr(multiprocessing, 'x', 1)\n"
        "    context = multiprocessing.get_context('spawn')\n"
        "    context._name\n"
        "    _jit.numba()._x\n"
        "    return Task(key, function, _data_producer=True), nb.njit(cache=True), types.float64\n"
    )
    assert scan_source(source) == [
        (2, "private", "dask._task_spec.Task"),
        (5, "deprecated", "numba.pycc.CC"),
        (8, "patch", "multiprocessing.util.spawnv_passfds"),
        (9, "private", "multiprocessing.util._exit_function"),
        (11, "private", "numba.core._helper"),
        (12, "private", "numba._private_thing"),
        (13, "patch", "multiprocessing.x"),
        (15, "private", "multiprocessing.get_context()._name"),
        (16, "private", "numba._x"),
        (17, "private", "dask._task_spec.Task(_data_producer=)"),
    ]


def test_no_private_part_of_a_dependency_is_used_unless_it_is_listed():
    uses = scan()
    unlisted = [f"{file}:{line}: {kind} {name}" for (file, name), (line, kind) in uses.items()
                if (file, name) not in ALLOWED]
    if unlisted:
        more = f" (and {len(unlisted) - 1} more)" if len(unlisted) > 1 else ""
        pytest.fail(f"{unlisted[0]}{more}: use a public API, or list it in tests/test_private_imports.py "
                    "ALLOWED with its pinned upper bound and reason", pytrace=False)


def test_every_listed_private_part_is_still_used():
    uses = scan()
    stale = [f"{file}: {name}" for file, name in ALLOWED if (file, name) not in uses]
    if stale:
        pytest.fail(f"{stale[0]} is listed in ALLOWED but no longer used: take it off the list "
                    "(and its pin, if nothing else needs it)", pytrace=False)


def test_every_listed_bound_is_the_pin_in_pyproject():
    dependencies = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    for (file, name), allowed in ALLOWED.items():
        if allowed.bound not in dependencies:
            pytest.fail(f"{file}: {name} needs {allowed.bound!r} in pyproject.toml's dependencies "
                        f"(they are {dependencies})", pytrace=False)
        if not re.search(r",\s*<", allowed.bound):
            pytest.fail(f"{file}: {name}: {allowed.bound!r} has no upper bound", pytrace=False)


@pytest.mark.parametrize("key", sorted(ALLOWED), ids=lambda key: key[1])
def test_the_installed_packages_still_have_each_listed_private_part(key):
    """The line a new release that moved a private part gives, before anything else breaks."""
    allowed = ALLOWED[key]
    project = re.match(r"[A-Za-z0-9_.-]+", allowed.bound).group(0)
    installed = importlib.metadata.version(project)
    try:
        problem = allowed.probe()
    except Exception as exc:  # noqa: BLE001 - an import or a call the release no longer has
        problem = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    if problem:
        pytest.fail(f"{key[0]}: {key[1]}: {problem} ({project} {installed} installed; the pin is "
                    f"{allowed.bound!r})", pytrace=False)


def test_the_pins_hold_for_the_installed_packages():
    """The environment the tests run in is one the pins allow."""
    from packaging.requirements import Requirement

    for bound in sorted({allowed.bound for allowed in ALLOWED.values()}):
        requirement = Requirement(bound)
        installed = importlib.metadata.version(requirement.name)
        assert requirement.specifier.contains(installed, prereleases=True), \
            f"{requirement.name} {installed} is installed; pyproject pins {bound}"



def test_a_dask_without_the_flag_stops_a_study_with_one_line(tmp_path, monkeypatch):
    """A Dask installed outside the pin whose Task no longer takes the flag: the study stops at its
    first cell with one line naming the pin, before any cell runs (not a TypeError from inside)."""
    import dask._task_spec

    from ilcforce.study import StudyRunError, run_study

    from test_study import small_study

    class TaskOfAnotherRelease:
        def __init__(self, key, func, *args):
            self.key, self.func, self.args = key, func, args

    monkeypatch.setattr(dask._task_spec, "Task", TaskOfAnotherRelease)
    with pytest.raises(StudyRunError) as caught:
        run_study(small_study(), tmp_path, workers=2)
    message = str(caught.value)
    assert "\n" not in message and f"pip install '{DASK}'" in message, message
    assert "TypeError" in message and "_data_producer" in message, message
    from ilcforce.study import read_study

    path = tmp_path / "studies" / "tiny.h5"
    assert not path.exists() or read_study(path).cells.empty
