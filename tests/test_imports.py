"""The package's import graph: no circle anywhere, and the library never imports the
commands (``hnn_pl/commands/``; ``hnn_pl/__main__.py`` is their entry point). Every
``import`` counts, at module level or inside a function: a function-level import is
still a dependency."""

from __future__ import annotations

import ast
from pathlib import Path

import hnn_pl

PACKAGE = Path(hnn_pl.__file__).parent


def _module(path: Path) -> str:
    parts = ["hnn_pl", *path.relative_to(PACKAGE).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _graph() -> dict[str, set[str]]:
    """module → the package modules it imports (``from a import b`` is ``a.b`` when
    ``a.b`` is a module, else ``a``)."""
    modules = {_module(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                subs = {f"{node.module}.{a.name}" for a in node.names}
                deps |= (subs & modules.keys()) or {node.module}
        graph[name] = {d for d in deps if d in modules and d != name}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                return stack[stack.index(d) :] + [d]
            if d not in state and (found := visit(d)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_graph_sees_imports_inside_functions():
    graph = _graph()
    assert "hnn_pl.evaluation" in graph["hnn_pl.models.base"]  # a function-level import
    assert "hnn_pl.commands.cli" in graph["hnn_pl.commands.reproduce"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_no_import_circle():
    assert _cycle(_graph()) is None


def test_the_library_never_imports_the_commands():
    offenders = sorted(
        f"{m} -> {d}"
        for m, deps in _graph().items()
        if not m.startswith(("hnn_pl.commands", "hnn_pl.__main__"))
        for d in deps
        if d.startswith("hnn_pl.commands")
    )
    assert offenders == []


def test_tasks_is_plain_data():
    assert _graph()["hnn_pl.tasks"] == set()
