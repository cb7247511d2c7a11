"""The layout shows the architecture: the package's imports run one way (no cycle, at any depth of a
function), nothing in the library imports the command line, the package holds no benchmark, and the
top level stays small enough to read."""

from __future__ import annotations

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "ilcforce"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports() -> dict[str, set[str]]:
    """module -> the ilcforce modules it imports (top level or inside a function), by name."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        found: set[str] = set()
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
                # `from package import module` imports the module; `from module import name`, the module
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
            else:
                continue
            found |= {t for t in targets if t in modules and t != name}
        graph[name] = found
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_package_has_no_import_cycle():
    graph = _imports()
    assert graph["ilcforce.cli.main"], "the import reader found nothing: the test would pass vacuously"
    cycle = _cycle(graph)
    assert cycle is None, " -> ".join(cycle)


def test_a_constructed_cycle_is_found():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_nothing_in_the_library_imports_the_command_line():
    offenders = sorted(f"{name} -> {target}" for name, targets in _imports().items()
                       if not name.startswith("ilcforce.cli") and name != "ilcforce.__main__"
                       for target in targets if target.startswith("ilcforce.cli"))
    assert offenders == []


def test_the_package_holds_no_benchmark_and_a_small_top_level():
    assert not [p for p in PACKAGE.rglob("*.py") if p.name.startswith("bench")]
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= 20, top


def _robot_names() -> set[str]:
    """Every registered robot's model name, module name and class names (ilcforce.plants.MODELS)."""
    from ilcforce.plants import MODELS

    return {part.rpartition(".")[2] for model, entry in MODELS.items() for part in (model, *entry[:3])}


def _named_robots(source: str, names: set[str]) -> list[tuple[int, str]]:
    """(line, text) of each place the code of ``source`` names a robot: an identifier, an attribute, an
    import or a string that is not a docstring holding one of ``names`` as a word. Comments and
    docstrings (prose, pointers into docs/model.md) are not code."""
    tree = ast.parse(source)
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                docstrings.add(id(first.value))
    pattern = re.compile(r"(?<![A-Za-z0-9_])(" + "|".join(map(re.escape, sorted(names))) + r")(?![A-Za-z0-9_])")
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            texts = [node.value]
        elif isinstance(node, ast.Name):
            texts = [node.id]
        elif isinstance(node, ast.Attribute):
            texts = [node.attr]
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            texts = [alias.name for alias in node.names] + [getattr(node, "module", None) or ""]
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
            texts = [node.name]
        elif isinstance(node, ast.arg):
            texts = [node.arg]
        else:
            continue
        found += [(node.lineno, text) for text in texts for part in re.split(r"[.]", text) if pattern.search(part)]
    return found


def test_no_module_outside_plants_names_a_robot():
    """docs/design.md: nothing outside ilcforce/plants/ knows which robot it simulates. The laws, the
    configuration and the report reach every plant-specific fact (regressor, parameters, default
    perturbation, working mode, gravity) through the plant interface and the registry."""
    from ilcforce.plants import MODELS, TITLES, plant_title

    names = _robot_names()
    assert {"fivebar", "serial2r", "FiveBar", "Serial2RParams"} <= names
    assert set(TITLES) == set(MODELS) and plant_title("serial2r") == "serial 2R arm"  # prose for the report
    offenders = [f"{path.relative_to(PACKAGE.parent)}:{line}: {text[:80]!r}"
                 for path in sorted(PACKAGE.rglob("*.py")) if "plants" not in path.relative_to(PACKAGE).parts[:1]
                 for line, text in _named_robots(path.read_text(encoding="utf-8"), names)]
    assert offenders == [], "modules outside ilcforce/plants/ name a robot:\n" + "\n".join(offenders)


def test_the_robot_name_scan_finds_code_not_prose():
    names = {"fivebar", "serial2r", "FiveBarParams"}
    code = ('"""The five-bar and the serial2r arm (docs/model.md#serial2r)."""\n'
            "from ilcforce.plants.fivebar import FiveBarParams  # fivebar\n"
            "def f(model):\n    '''on the fivebar'''\n    return model == \"serial2r\"\n"
            "x = plants.fivebar.thing\nlabel = 'five-bar: kg m^2'\n")
    assert sorted({line for line, _ in _named_robots(code, names)}) == [2, 5, 6]
