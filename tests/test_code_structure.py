"""Structure rules of the code base, checked on the source with ``ast`` (nothing is imported):

* no function in ``stealth_ns/`` or ``method_configs/`` is longer than :data:`MAX_FUNCTION_LINES`
  lines, counted from its first statement after the docstring to its last line (signature and
  docstring excluded; blank lines and comments inside count);
* no import cycle among the ``stealth_ns`` modules (``method_configs/`` is installed as
  ``stealth_ns.method_configs``). Only imports that run when a module is imported count: those at
  module level, also inside ``if`` / ``try`` / ``with`` / class bodies, but neither those inside
  functions (run later) nor those under ``if TYPE_CHECKING:`` (never run).

``python tests/test_code_structure.py`` prints every offender.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "stealth_ns"
SOURCES = {ROOT / "stealth_ns": "stealth_ns", ROOT / "method_configs": "stealth_ns.method_configs"}
"""Source folder -> the package it is installed as (pyproject.toml's ``package-dir``)."""
MAX_FUNCTION_LINES = 80


def source_files(sources: dict[Path, str] = SOURCES) -> dict[str, Path]:
    """Every module of the package: dotted name -> file."""
    modules = {}
    for folder, package in sources.items():
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join((package, *parts))] = path
    return modules


def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _shown(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


# --------------------------------------------------------------------------------- function length


def function_length(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the first statement after the docstring to the end of the function (0 when the
    body is only a docstring)."""
    body = node.body
    first = body[0]
    if (
        isinstance(first, ast.Expr)
        and isinstance(first.value, ast.Constant)
        and isinstance(first.value.value, str)
    ):
        if len(body) == 1:
            return 0
        first = body[1]
    return node.end_lineno - first.lineno + 1


def long_functions(sources: dict[Path, str] = SOURCES, limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """``path:line name (N lines)`` of every function longer than ``limit`` lines, nested ones too."""
    found = []
    for path in source_files(sources).values():
        for node in ast.walk(_parse(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = function_length(node)
                if n > limit:
                    found.append(f"{_shown(path)}:{node.lineno} {node.name} ({n} lines)")
    return found


# ---------------------------------------------------------------------------------- import cycles


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _import_time_imports(body: list[ast.stmt]) -> Iterator[ast.Import | ast.ImportFrom]:
    """The import statements of ``body`` that run on import: not in functions (nor lambdas), not
    under ``if TYPE_CHECKING:`` (its ``else`` does run)."""
    for stmt in body:
        if isinstance(stmt, (ast.Import, ast.ImportFrom)):
            yield stmt
        elif isinstance(stmt, ast.If):
            if not _is_type_checking(stmt.test):
                yield from _import_time_imports(stmt.body)
            yield from _import_time_imports(stmt.orelse)
        elif isinstance(stmt, (ast.Try, getattr(ast, "TryStar", ast.Try))):
            for block in (stmt.body, *(h.body for h in stmt.handlers), stmt.orelse, stmt.finalbody):
                yield from _import_time_imports(block)
        elif isinstance(stmt, (ast.With, ast.AsyncWith, ast.ClassDef, ast.For, ast.While)):
            yield from _import_time_imports(stmt.body)
            yield from _import_time_imports(getattr(stmt, "orelse", []))


def _targets(stmt: ast.Import | ast.ImportFrom, module: str, is_package: bool, known: set[str]) -> list[str]:
    """The package's modules an import statement of ``module`` loads by name (the parent packages
    it also initialises are not counted: a package importing its own submodules is no cycle)."""
    if isinstance(stmt, ast.Import):
        return [alias.name for alias in stmt.names]
    if stmt.level:
        package = module if is_package else module.rpartition(".")[0]
        for _ in range(stmt.level - 1):
            package = package.rpartition(".")[0]
        base = f"{package}.{stmt.module}" if stmt.module else package
    else:
        base = stmt.module or ""
    return [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in stmt.names]


def import_graph(sources: dict[Path, str] = SOURCES) -> dict[str, dict[str, int]]:
    """module -> {imported package module: line of the first such import}."""
    files = source_files(sources)
    known = set(files)
    graph: dict[str, dict[str, int]] = {}
    for module, path in files.items():
        edges: dict[str, int] = {}
        for stmt in _import_time_imports(_parse(path).body):
            for target in _targets(stmt, module, path.name == "__init__.py", known):
                if target in known and target != module:
                    edges.setdefault(target, stmt.lineno)
        graph[module] = edges
    return graph


def _strongly_connected(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return components


def import_cycles(sources: dict[Path, str] = SOURCES) -> list[str]:
    """One line per cycle: its modules, and each import inside it (``a:LINE -> b``)."""
    graph = import_graph(sources)
    files = source_files(sources)
    lines = []
    for component in _strongly_connected(graph):
        members = set(component)
        edges = [
            f"{_shown(files[a])}:{line} -> {b}"
            for a in component
            for b, line in sorted(graph[a].items())
            if b in members
        ]
        lines.append(f"{' <-> '.join(component)}: {'; '.join(edges)}")
    return lines


# ------------------------------------------------------------------------------------------ tests


def test_no_function_is_longer_than_80_lines():
    found = long_functions()
    assert not found, (
        f"{len(found)} function(s) over {MAX_FUNCTION_LINES} lines (docstring excluded):\n" + "\n".join(found)
    )


def test_no_import_cycle_among_the_package_modules():
    found = import_cycles()
    assert not found, f"{len(found)} import cycle(s) among the {PACKAGE} modules:\n" + "\n".join(found)


def test_the_checks_see_what_they_should(tmp_path):
    """The rules themselves: a docstring does not count, TYPE_CHECKING and function-level imports
    do not make cycles, module-level ones do; the whole package is scanned."""
    tree = ast.parse('def f():\n    """Doc\n    string."""\n    a = 1\n\n    return a\n')
    assert function_length(tree.body[0]) == 3
    assert function_length(ast.parse('def g():\n    """Only a docstring."""\n').body[0]) == 0
    source = (
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    import stealth_ns.a\nelse:\n    import stealth_ns.b\n"
        "def f():\n    import stealth_ns.c\n"
        "try:\n    from . import d\nexcept ImportError:\n    pass\n"
        "class K:\n    from .e import thing\n"
    )
    stmts = list(_import_time_imports(ast.parse(source).body))
    known = {"stealth_ns.x.d", "stealth_ns.x.e"}
    targets = [t for s in stmts for t in _targets(s, "stealth_ns.x.m", False, known)]
    assert targets == ["typing", "stealth_ns.b", "stealth_ns.x.d", "stealth_ns.x.e"]
    assert _strongly_connected({"a": {"b": 1}, "b": {"c": 2}, "c": {"a": 3}, "d": {"a": 4}}) == [
        ["a", "b", "c"]
    ]
    # a package on disk: p.a <-> p.sub.b at module level is a cycle; p.a -> p.c -> p.a is none (p.c
    # imports p.a only inside a function and under TYPE_CHECKING), nor p/__init__ importing p.a
    files = {
        "__init__.py": "from p import a\n",
        "a.py": "from .sub import b\nfrom . import c\n",
        "sub/__init__.py": "",
        "sub/b.py": "import p.a\n\ndef f():\n" + "    x = 1\n" * 81,
        "c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from p import a\n"
        "def g():\n    from . import a\n",
    }
    for name, text in files.items():
        (tmp_path / "p" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "p" / name).write_text(text)
    sources = {tmp_path / "p": "p"}
    cycle = f"p.a <-> p.sub.b: {tmp_path}/p/a.py:1 -> p.sub.b; {tmp_path}/p/sub/b.py:1 -> p.a"
    assert import_cycles(sources) == [cycle]
    assert long_functions(sources) == [f"{tmp_path}/p/sub/b.py:3 f (81 lines)"]
    modules = source_files()
    assert {"stealth_ns.cli", "stealth_ns.attack", "stealth_ns.method_configs.attack_experiments"} <= set(
        modules
    )
    assert "stealth_ns.attack.config" in import_graph()["stealth_ns.attack.validation"]


if __name__ == "__main__":
    print("\n".join(long_functions() + import_cycles()) or "no offenders")
