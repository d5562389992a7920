"""The package's import graph: no circle anywhere, and three layers: the library, the
experiments that reproduce the paper on it (``hnn_pl/experiments/``), and the commands
(``hnn_pl/commands/``; ``hnn_pl/__main__.py`` is their entry point). The library imports
neither of the others, the experiments never import the commands. Every ``import``
counts, at module level or inside a function: a function-level import is still a
dependency."""

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


COMMANDS = ("hnn_pl.commands", "hnn_pl.__main__")
EXPERIMENTS = ("hnn_pl.experiments",)


def _in(module: str, packages: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in packages)


def _offenders(importers: list[str], imported: tuple[str, ...]) -> list[str]:
    """``m -> d`` for every module ``m`` of ``importers`` that imports a module ``d`` of
    the packages ``imported``."""
    graph = _graph()
    return sorted(f"{m} -> {d}" for m in importers for d in graph[m] if _in(d, imported))


def test_the_library_never_imports_the_commands_or_the_experiments():
    library = [m for m in _graph() if not _in(m, COMMANDS + EXPERIMENTS)]
    assert {"hnn_pl", "hnn_pl.tasks", "hnn_pl.evaluation.metrics"} <= set(library)
    assert _offenders(library, COMMANDS + EXPERIMENTS) == []


def test_the_experiments_never_import_the_commands():
    experiments = [m for m in _graph() if _in(m, EXPERIMENTS)]
    assert "hnn_pl.experiments.collect" in experiments
    assert _offenders(experiments, ("hnn_pl.experiments.tta",))  # the check sees imports
    assert _offenders(experiments, COMMANDS) == []


def test_tasks_and_the_paper_s_table_are_plain_data():
    graph = _graph()
    assert graph["hnn_pl.tasks"] == set()
    assert graph["hnn_pl.experiments.paper"] == set()
