"""The package's import graph: circles (import cycles) and upward imports.

    python scripts/import_graph.py [PACKAGE_DIR] [--edges]

Reads every module of the package with ``ast`` (nothing is imported or run) and counts an edge for
every ``import`` of one of our modules, at the top of a file or inside a function alike: a lazy
import still ties the two files together. Imports under ``if TYPE_CHECKING:`` are left out (they
never run). ``from . import x`` counts as an import of the submodule ``x`` where there is one.
Importing ``a.b`` runs ``a/__init__.py`` too; that implied edge is not counted (as grimp and
pydeps do not), so a package's ``__init__`` is judged by what it imports itself.

Layers, bottom to top; an import is *upward* when a module imports one in a higher layer
(imports within a layer are fine, circles are counted apart):

0. foundation: the flight record and its maths (quaternion, flight, the earth and atmosphere),
   the readers, the estimators, the parameter declarations (paramspec), the simulator, the
   input side of a live link (link, loss, recorder), small shared helpers (errors, events,
   outputs, progress, signals, growing, memory, kernel_cache, declination, phase, aiding).
1. core: the estimation core (core/: runner, warmup, the parameter sets built from the
   declarations), live's stepping of the core (live.estimation), scoring (scoring/) and
   replay's report (commands.report, which live's final table uses too).
2. view: everything that draws with Rerun and where it goes (view/, live's display and the
   sink included). It shows what the commands produce and imports from them only their result
   types (for type checking), so it sits below them: replay, live and ``bench --live`` hand
   their results to it.
3. commands: replay, evaluate and its report, tune, bench, info (commands/), the live session.
4. front: the command line (cli, __main__) and the Python API (the package's ``__init__``).

A module the table does not place is an error: a new module is given its layer here.
Prints the circles (each a strongly connected set of modules, with the imports that close it),
the upward imports with file and line, and any import of a module the package does not hold (a
file moved, or never added: CI fails on it); exit status 1 when there is any.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from pathlib import Path

LAYERS = [
    ("foundation", ["_version", "quaternion", "flight", "earth", "trim", "diagcolumns", "errors", "events", "growing", "memory", "kernel_cache", "signals",
                    "progress", "outputs", "declination", "phase", "aiding", "paramspec", "readers", "estimators",
                    "sim", "live.link", "live.loss", "live.recorder"]),
    ("core", ["core", "live.estimation", "scoring", "commands.report"]),
    ("view", ["view"]),
    ("commands", ["commands", "live", "live.session"]),
    ("front", ["cli", "__main__", ""]),  # "": the package's __init__, the Python API
]


@dataclass(frozen=True)
class Edge:
    source: str  # importing module, dotted below the package ("" = the package's __init__)
    target: str
    line: int
    lazy: bool  # inside a function


def module_names(root: Path) -> dict[str, Path]:
    """Dotted name below the package -> file."""
    names = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        names[".".join(parts)] = path
    return names


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST):
    """(node, inside a function) for every import that can run (not under TYPE_CHECKING)."""
    def visit(node, lazy):
        for child in ast.iter_child_nodes(node):
            if not isinstance(child, (ast.stmt, ast.excepthandler, ast.match_case)):
                continue  # an import is a statement: expressions never hold one
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                for other in child.orelse:
                    yield from visit(other, lazy)
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                yield child, lazy
            yield from visit(child, lazy or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)))
    yield from visit(tree, False)


def edges(root: Path, package: str, missing: list | None = None) -> tuple[dict[str, Path], list[Edge]]:
    """Every module and every import between two of them; an import of one of ours that names no
    module of the package (a file moved or never added) goes to ``missing``, where given."""
    modules = module_names(root)
    found = []
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        here = name.split(".") if name else []
        tree = ast.parse(path.read_text(), str(path))
        for node, lazy in _imports(tree):
            targets = []
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name == package or alias.name.startswith(package + "."):
                        targets.append(alias.name[len(package) + 1:])
            else:
                if node.level:
                    base = here if is_package else here[:-1]
                    base = base[:len(base) - (node.level - 1)] if node.level > 1 else base
                    stem = ".".join(base + ([node.module] if node.module else []))
                elif node.module and (node.module == package or node.module.startswith(package + ".")):
                    stem = node.module[len(package) + 1:]
                else:
                    continue
                for alias in node.names:
                    sub = f"{stem}.{alias.name}" if stem else alias.name
                    targets.append(sub if sub in modules else stem)
            for target in targets:
                if target in modules and target != name:
                    found.append(Edge(name, target, node.lineno, lazy))
                elif target not in modules and missing is not None:
                    missing.append(Edge(name, target, node.lineno, lazy))
    return modules, sorted(set(found), key=lambda e: (e.source, e.line, e.target))  # one per line


def layer_of(name: str) -> int:
    """The layer of a module: its own entry, else its package's (the longest prefix)."""
    best, best_len = None, -1
    for index, (_, members) in enumerate(LAYERS):
        for member in members:
            if (name == member or (member and name.startswith(member + "."))) and len(member) > best_len:
                best, best_len = index, len(member)
    if best is None:
        raise KeyError(f"module {name!r} has no layer: give it one in scripts/import_graph.py's LAYERS")
    return best


def cycles(modules, found: list[Edge]) -> list[list[str]]:
    """Strongly connected sets of more than one module (Tarjan), each sorted; largest first."""
    graph = {m: sorted({e.target for e in found if e.source == m}) for m in modules}
    index, low, stack, on_stack, result = {}, {}, [], set(), []

    def connect(v):  # recursive: the package has a few dozen modules
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                result.append(sorted(group))

    for v in graph:
        if v not in index:
            connect(v)
    return sorted(result, key=lambda g: (-len(g), g))


def upward(found: list[Edge]) -> list[Edge]:
    return [e for e in found if layer_of(e.source) < layer_of(e.target)]


def _show(name: str, package: str) -> str:
    return f"{package}.{name}" if name else package


def main(argv: list[str]) -> int:
    show_edges = "--edges" in argv
    argv = [a for a in argv if a != "--edges"]
    root = Path(argv[0] if argv else Path(__file__).resolve().parent.parent / "mavattitude").resolve()
    package = root.name
    missing: list[Edge] = []
    modules, found = edges(root, package, missing)
    circles = cycles(modules, found)
    up = upward(found)
    if show_edges:
        for e in sorted(found, key=lambda e: (e.source, e.target)):
            print(f"{_show(e.source, package)} -> {_show(e.target, package)} (line {e.line}{', lazy' if e.lazy else ''})")
    for group in circles:
        print(f"circle of {len(group)} modules: {', '.join(_show(m, package) for m in group)}")
        members = set(group)
        for e in found:
            if e.source in members and e.target in members:
                print(f"    {_show(e.source, package)}:{e.line} -> {_show(e.target, package)}"
                      f"{' (in a function)' if e.lazy else ''}")
    for e in up:
        print(f"upward: {_show(e.source, package)}:{e.line} ({LAYERS[layer_of(e.source)][0]}) -> "
              f"{_show(e.target, package)} ({LAYERS[layer_of(e.target)][0]}){' (in a function)' if e.lazy else ''}")
    for e in missing:
        print(f"missing: {_show(e.source, package)}:{e.line} imports {package}.{e.target}, which is no module here")
    in_circles = sum(len(g) for g in circles)
    print(f"{len(modules)} modules, {len(found)} imports: {len(circles)} circles ({in_circles} modules in them), "
          f"{len(up)} upward imports, {len(missing)} imports of no module")
    return 1 if circles or up or missing else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
