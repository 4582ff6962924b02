"""Structure rules of the code base, checked on the source with ``ast`` (nothing is imported):

* no function in ``stealth_ns/`` or ``method_configs/`` is longer than :data:`MAX_FUNCTION_LINES`
  lines, counted from its first statement after the docstring to its last line (signature and
  docstring excluded; blank lines and comments inside count);
* no module is longer than :data:`MAX_MODULE_LINES` lines;
* no circle among the top-level packages of ``stealth_ns`` either (``a`` imports from ``b`` and ``b``,
  through any path, from ``a``), and at most :data:`MAX_LOOSE_MODULES` modules sit directly in it;
* no import cycle among the ``stealth_ns`` modules (``method_configs/`` is installed as
  ``stealth_ns.method_configs``), counting **every** import statement: at module level, inside
  functions (run later, but a dependency all the same) and under ``if TYPE_CHECKING:``;
* layers point down: every module belongs to one of :data:`LAYERS`, and no import (at any depth)
  goes from a module to one of a higher layer;
* pyproject.toml lists every package of ``stealth_ns/`` (a package it misses is not installed by a
  regular, non-editable install).

``python tests/test_code_structure.py`` prints every offender.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "stealth_ns"
SOURCES = {ROOT / "stealth_ns": "stealth_ns", ROOT / "method_configs": "stealth_ns.method_configs"}
"""Source folder -> the package it is installed as (pyproject.toml's ``package-dir``)."""
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 600

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("foundation", ("stealth_ns", "foundation")),
    ("rasterization", ("raster",)),
    ("math and data", ("images", "gaussians", "attack", "scene_generator", "datasets", "difficulty")),
    ("the nerfstudio method", ("method",)),
    ("defences", ("defences",)),
    ("method configs", ("method_configs",)),
    ("poisoned datasets", ("poisoned_datasets",)),
    ("trained runs", ("runs",)),
    ("evaluation", ("defence_eval", "scan")),
    ("report", ("report",)),
    ("bench", ("bench",)),
    ("commands", ("demo", "cli")),
)  # fmt: skip
"""The layers, lowest first, each with the packages (and the few top-level modules) in it, by their
names under ``stealth_ns`` (a package's name covers its modules; the longest matching name decides;
``stealth_ns`` itself is the package's ``__init__`` alone). A module may import from its own layer and
the ones below, never from one above."""
MAX_LOOSE_MODULES = 5
"""Most modules directly in ``stealth_ns/`` (``__init__`` included): the top level holds the
entry points; everything else lives in a package named for its concept."""


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


def _imports(tree: ast.Module) -> Iterator[ast.Import | ast.ImportFrom]:
    """Every import statement of a module, at any depth (functions, classes, ``TYPE_CHECKING``)."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node


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
        for stmt in _imports(_parse(path)):
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


def top_package(module: str, package: str = PACKAGE) -> str:
    """The package (or loose module) directly under ``package`` that holds ``module``."""
    parts = module.split(".")
    return module if len(parts) < 2 else ".".join(parts[:2])


def package_graph(sources: dict[Path, str] = SOURCES) -> dict[str, dict[str, str]]:
    """Top-level package -> {package it imports: one import that makes the edge (``a -> b``)}."""
    graph: dict[str, dict[str, str]] = {}
    for module, edges in import_graph(sources).items():
        here = top_package(module)
        graph.setdefault(here, {})
        for target in edges:
            there = top_package(target)
            if there != here:
                graph[here].setdefault(there, f"{module} -> {target}")
    for edges in list(graph.values()):
        for there in edges:
            graph.setdefault(there, {})
    return graph


def package_cycles(sources: dict[Path, str] = SOURCES) -> list[str]:
    """One line per circle among the top-level packages, with one import of each edge in it."""
    graph = package_graph(sources)
    lines = []
    for component in _strongly_connected({k: dict.fromkeys(v, 0) for k, v in graph.items()}):
        members = set(component)
        edges = [graph[a][b] for a in component for b in sorted(graph[a]) if b in members]
        lines.append(f"{' <-> '.join(component)}: {'; '.join(edges)}")
    return lines


def loose_modules(folder: Path = ROOT / PACKAGE) -> list[str]:
    """The modules directly in the package's folder (not in a sub-package)."""
    return sorted(path.name for path in folder.glob("*.py"))


# ---------------------------------------------------------------------------------- layers, sizes


def layer_of(module: str, package: str = PACKAGE, layers: tuple = LAYERS) -> int | None:
    """Index in ``layers`` of a module (longest matching name wins), None when it is in none."""
    best, best_len = None, -1
    for index, (_, names) in enumerate(layers):
        for name in names:
            full = package if name == package else f"{package}.{name}"
            inside = module == full or (name != package and module.startswith(full + "."))
            if inside and len(full) > best_len:
                best, best_len = index, len(full)
    return best


def unplaced_modules(sources: dict[Path, str] = SOURCES, layers: tuple = LAYERS) -> list[str]:
    """Modules that belong to no layer (a new module must be given its place)."""
    return [m for m in source_files(sources) if layer_of(m, PACKAGE, layers) is None]


def upward_imports(sources: dict[Path, str] = SOURCES, layers: tuple = LAYERS) -> list[str]:
    """``path:LINE a (layer) -> b (higher layer)`` for every import of a higher layer's module."""
    files = source_files(sources)
    found = []
    for module, edges in import_graph(sources).items():
        low = layer_of(module, PACKAGE, layers)
        for target, line in sorted(edges.items()):
            high = layer_of(target, PACKAGE, layers)
            if low is not None and high is not None and high > low:
                where = f"{_shown(files[module])}:{line}"
                found.append(f"{where} {module} ({layers[low][0]}) -> {target} ({layers[high][0]})")
    return found


def long_modules(sources: dict[Path, str] = SOURCES, limit: int = MAX_MODULE_LINES) -> list[str]:
    """``path (N lines)`` of every module longer than ``limit`` lines."""
    found = []
    for path in source_files(sources).values():
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > limit:
            found.append(f"{_shown(path)} ({n} lines)")
    return found


def listed_packages(pyproject: Path = ROOT / "pyproject.toml") -> set[str]:
    """The ``packages`` of pyproject.toml's ``[tool.setuptools]``."""
    text = pyproject.read_text(encoding="utf-8")
    block = re.search(r"^packages\s*=\s*\[(.*?)\]", text, re.S | re.M)
    assert block, f"no packages list in {pyproject}"
    return set(re.findall(r'"([^"]+)"', block.group(1)))


def package_folders(sources: dict[Path, str] = SOURCES) -> set[str]:
    """Every package (a folder with ``__init__.py``) under the source folders, as installed."""
    return {m for m, path in source_files(sources).items() if path.name == "__init__.py"}


# ------------------------------------------------------------------------------------------ tests


def test_no_function_is_longer_than_80_lines():
    found = long_functions()
    assert not found, (
        f"{len(found)} function(s) over {MAX_FUNCTION_LINES} lines (docstring excluded):\n" + "\n".join(found)
    )


def test_no_import_cycle_among_the_package_modules():
    found = import_cycles()
    assert not found, f"{len(found)} import cycle(s) among the {PACKAGE} modules:\n" + "\n".join(found)


def test_no_circle_among_the_packages():
    found = package_cycles()
    assert not found, f"{len(found)} circle(s) among the {PACKAGE} packages:\n" + "\n".join(found)


def test_few_modules_are_left_loose_at_the_top():
    found = loose_modules()
    assert len(found) <= MAX_LOOSE_MODULES, (
        f"{len(found)} modules directly in {PACKAGE}/ (at most {MAX_LOOSE_MODULES}; give each a package "
        f"named for its concept): {', '.join(found)}"
    )


def test_no_module_is_longer_than_600_lines():
    found = long_modules()
    assert not found, f"{len(found)} module(s) over {MAX_MODULE_LINES} lines:\n" + "\n".join(found)


def test_every_module_has_a_layer_and_imports_point_down():
    unplaced = unplaced_modules()
    assert not unplaced, "module(s) in no layer of LAYERS (give each its place):\n" + "\n".join(unplaced)
    found = upward_imports()
    assert not found, f"{len(found)} import(s) from a lower layer to a higher one:\n" + "\n".join(found)


def test_pyproject_lists_every_package():
    listed, present = listed_packages(), package_folders()
    assert listed == present, f"missing from pyproject.toml: {sorted(present - listed)}; " + (
        f"listed but absent: {sorted(listed - present)}"
    )


def test_the_checks_see_what_they_should(tmp_path):
    """The rules themselves: a docstring does not count; imports at any depth make edges (module
    level, functions, classes, TYPE_CHECKING); layers by the longest name; the whole package is scanned."""
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
    stmts = list(_imports(ast.parse(source)))
    known = {"stealth_ns.x.d", "stealth_ns.x.e"}
    targets = sorted(t for s in stmts for t in _targets(s, "stealth_ns.x.m", False, known))
    assert targets == [
        "stealth_ns.a",
        "stealth_ns.b",
        "stealth_ns.c",
        "stealth_ns.x.d",
        "stealth_ns.x.e",
        "typing",
    ]
    assert _strongly_connected({"a": {"b": 1}, "b": {"c": 2}, "c": {"a": 3}, "d": {"a": 4}}) == [
        ["a", "b", "c"]
    ]
    # a package on disk: p.a <-> p.sub.b at module level is a cycle, and so is p.a -> p.c -> p.a
    # (p.c imports p.a inside a function); p/__init__ importing p.a is none
    files = {
        "__init__.py": "from p import a\n",
        "a.py": "from .sub import b\nfrom . import c\n",
        "sub/__init__.py": "",
        "sub/b.py": "import p.a\n\ndef f():\n" + "    x = 1\n" * 81,
        "c.py": "def g():\n    from . import a\n",
        "d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from p import c\n",
    }
    for name, text in files.items():
        (tmp_path / "p" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "p" / name).write_text(text)
    sources = {tmp_path / "p": "p"}
    (circle,) = package_cycles(sources)
    assert circle.startswith("p.a <-> p.c <-> p.sub: ")
    assert top_package("p.sub.b") == "p.sub" and top_package("p") == "p"
    assert loose_modules(tmp_path / "p") == ["__init__.py", "a.py", "c.py", "d.py"]
    (cycle,) = import_cycles(sources)
    assert cycle.startswith("p.a <-> p.c <-> p.sub.b: ") and f"{tmp_path}/p/c.py:2 -> p.a" in cycle
    assert long_functions(sources) == [f"{tmp_path}/p/sub/b.py:3 f (81 lines)"]
    assert long_modules(sources, limit=83) == [f"{tmp_path}/p/sub/b.py (84 lines)"]
    assert long_modules(sources, limit=84) == []
    # layers: the longest name decides; an import of a higher layer is reported, even under TYPE_CHECKING
    layers = (("low", ("p", "c", "d")), ("mid", ("sub",)), ("high", ("a", "sub.b")))
    assert layer_of("p.sub.b", "p", layers) == 2 and layer_of("p.sub", "p", layers) == 1
    assert layer_of("p", "p", layers) == 0 and layer_of("q", "p", layers) is None
    assert layer_of("p.other", "p", layers) is None  # the root package's entry is its __init__ alone
    assert layer_of("stealth_ns.defences.signals") > layer_of("stealth_ns.method.model")
    assert (
        layer_of("stealth_ns.bench.plan") > layer_of("stealth_ns.report.write") > layer_of("stealth_ns.runs")
    )
    # the module-level edges of the real package are still seen
    assert "stealth_ns.attack.config" in import_graph()["stealth_ns.attack.validation"]
    modules = source_files()
    assert {"stealth_ns.cli", "stealth_ns.attack", "stealth_ns.method_configs.attack_experiments"} <= set(
        modules
    )
    assert "stealth_ns.report" in package_folders() and "stealth_ns.method_configs" in package_folders()


def test_upward_imports_and_unplaced_modules_are_found(tmp_path, monkeypatch):
    """On a small package: a function-level and a TYPE_CHECKING import of a higher layer are both
    reported, with their lines; a module of no layer is named."""
    files = {
        "__init__.py": "",
        "low.py": f"def f():\n    from {PACKAGE} import high\n",
        "mid.py": f"from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from {PACKAGE}.high import X\n",
        "high.py": "from . import low, mid\n",
        "stray.py": "",
    }
    (tmp_path / "p").mkdir()
    for name, text in files.items():
        (tmp_path / "p" / name).write_text(text)
    sources = {tmp_path / "p": PACKAGE}
    layers = (("base", (PACKAGE, "low")), ("middle", ("mid",)), ("top", ("high",)))
    found = upward_imports(sources, layers)
    assert found == [
        f"{tmp_path}/p/low.py:2 {PACKAGE}.low (base) -> {PACKAGE}.high (top)",
        f"{tmp_path}/p/mid.py:3 {PACKAGE}.mid (middle) -> {PACKAGE}.high (top)",
    ]
    assert unplaced_modules(sources, (("base", ("low", "mid", "high")),)) == [
        f"{PACKAGE}",
        f"{PACKAGE}.stray",
    ]


if __name__ == "__main__":
    found = long_functions() + long_modules() + import_cycles() + package_cycles() + unplaced_modules()
    found += upward_imports()
    print("\n".join(found) or "no offenders")
