"""The package's size budgets (issue 35), measured from the source so they stay met:
``hnn_pl/commands/`` at most 1,000 lines; no function over 60 lines (its docstring
aside) anywhere in ``hnn_pl/``. :func:`code_lines` counts a layer's code: lines that
are not blank, not a comment and not part of a docstring."""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

import hnn_pl

PACKAGE = Path(hnn_pl.__file__).parent
COMMANDS_LINES = 1000
FUNCTION_LINES = 60


def _docstring_lines(tree: ast.AST) -> set[int]:
    """Line numbers (1-based) of every module, class and function docstring."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                if isinstance(body[0].value.value, str):
                    lines |= set(range(body[0].lineno, body[0].end_lineno + 1))
    return lines


def _comment_only_lines(source: str) -> set[int]:
    """Line numbers holding a comment and nothing else."""
    code, comments = set(), set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments.add(tok.start[0])
        elif tok.type not in (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT):
            code |= set(range(tok.start[0], tok.end[0] + 1))
    return comments - code


def code_lines(path: Path) -> int:
    """Lines of ``path`` that are neither blank, a comment alone nor a docstring."""
    source = path.read_text()
    skip = _docstring_lines(ast.parse(source)) | _comment_only_lines(source)
    lines = source.splitlines()
    return sum(1 for i, line in enumerate(lines, 1) if line.strip() and i not in skip)


def function_lengths(path: Path, root: Path = PACKAGE) -> dict[str, int]:
    """``module:qualified name`` (the module relative to ``root``) → the function's
    lines, its decorators and ``def`` to its end, less its docstring's."""
    tree = ast.parse(path.read_text())
    found: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                start = min([child.lineno, *(d.lineno for d in child.decorator_list)])
                n = child.end_lineno - start + 1
                first = child.body[0]
                if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                    n -= first.end_lineno - first.lineno + 1
                found[f"{path.relative_to(root)}:{name}"] = n
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")

    visit(tree, "")
    return found


def layer(name: str) -> list[Path]:
    """The files of a layer: ``commands``, ``experiments`` or ``library`` (the rest)."""
    files = sorted(PACKAGE.rglob("*.py"))
    if name == "library":
        return [
            p for p in files if p.relative_to(PACKAGE).parts[0] not in ("commands", "experiments")
        ]
    return [p for p in files if p.relative_to(PACKAGE).parts[0] == name]


def test_commands_stay_small():
    """``hnn_pl/commands/`` (argument parsing and dispatch): at most 1,000 lines."""
    lines = sum(len(p.read_text().splitlines()) for p in layer("commands"))
    assert lines <= COMMANDS_LINES


def test_no_long_function():
    """No function of the package over 60 lines, its docstring aside."""
    lengths: dict[str, int] = {}
    for path in PACKAGE.rglob("*.py"):
        lengths |= function_lengths(path)
    long = {k: n for k, n in lengths.items() if n > FUNCTION_LINES}
    assert long == {}


def test_the_measures_count_what_they_say(tmp_path):
    path = tmp_path / "m.py"
    path.write_text(
        '"""module\ndoc"""\n\n# a comment\nx = 1  # kept\n\n\ndef f(a):\n'
        '    """doc\n    more"""\n    # why\n    return a\n'
    )
    assert code_lines(path) == 3  # x = 1, def f, return a
    assert function_lengths(path, tmp_path) == {"m.py:f": 3}


if __name__ == "__main__":  # the budgets measured: python tests/test_layout.py
    for name in ("commands", "experiments", "library"):
        files = layer(name)
        total = sum(len(p.read_text().splitlines()) for p in files)
        print(f"{name}: {total} lines, {sum(code_lines(p) for p in files)} code lines")
    lengths: dict[str, int] = {}
    for path in PACKAGE.rglob("*.py"):
        lengths |= function_lengths(path)
    for k, n in sorted(lengths.items(), key=lambda kv: -kv[1])[:8]:
        print(f"{n:4d} {k}")
