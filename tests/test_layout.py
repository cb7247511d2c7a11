"""The layout shows the architecture: the package's imports run one way (no cycle, at any depth of a
function), nothing in the library imports the command line, the package holds no benchmark, and the
top level stays small enough to read."""

from __future__ import annotations

import ast
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
