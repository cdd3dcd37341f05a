"""The package's import graph read from its source (AST), lazy imports included.

Importing a module only shows what its top level pulls in; an import inside a function
(a *lazy* import) runs later, and can close a cycle that no import-time check sees.  This
module parses every file under ``src/lodsprite`` and records each ``import`` and ``from
... import`` wherever it stands: at the top level, inside a function (``lazy``), or under
``if TYPE_CHECKING:`` (``type_only``: never executed, so it counts for no cycle).

``from lodsprite import Name`` goes through the package's PEP 562 facade: it is resolved
to the module that the facade's ``_LAZY`` table names for ``Name``.

A string that names a module of the package (``"lodsprite.manager.technique"``, or
``"lodsprite.manager.technique:create"`` as factories and entry points are written) is an
import that runs later through :mod:`importlib`: it is an edge too (``string``, counted
as lazy), so a dependency hidden in a string cannot close a cycle unseen.  A module
naming itself (a worker's factory handed to another process) is no edge, nor is a
string that is an entry-point group of ``pyproject.toml`` (``"lodsprite.techniques"``
names the group plug-ins register in, not a module to import) or a logger's name.

Used by ``tests/test_layering.py`` (the rules) and ``benchmarks/code_shape.py`` (the
figures: cycles, long modules, long functions).
"""

from __future__ import annotations

import ast
import tomllib
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
PACKAGE = "lodsprite"
#: The entry-point groups the project declares: names of groups, not of modules.
GROUPS = frozenset(tomllib.loads((ROOT / "pyproject.toml").read_text())
                   .get("project", {}).get("entry-points", {}))


@dataclass(frozen=True)
class Import:
    """One import statement's edge: ``source`` module imports ``target`` (a module of the
    package, or an outside top-level name such as ``moderngl``) at ``line``."""

    source: str
    target: str
    line: int
    lazy: bool
    type_only: bool
    string: bool = False


def module_files(src: Path = SRC) -> dict[str, Path]:
    """Every module of the package by dotted name (a package by its ``__init__``)."""
    found = {}
    for path in sorted((src / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _facade_table(files: dict[str, Path]) -> dict[str, str]:
    """The root package's ``_LAZY`` table: public name -> module."""
    tree = ast.parse(files[PACKAGE].read_text())
    for node in tree.body:
        if (isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "_LAZY" for t in node.targets)):
            return ast.literal_eval(node.value)
    return {}


class _Collector(ast.NodeVisitor):
    def __init__(self, module: str, is_package: bool, known: set[str],
                 facade: dict[str, str]) -> None:
        self.module, self.is_package = module, is_package
        self.known, self.facade = known, facade
        self.found: list[Import] = []
        self._depth = 0
        self._type_only = 0

    # --- scopes -------------------------------------------------------------------------
    def _function(self, node) -> None:
        self._depth += 1
        self.generic_visit(node)
        self._depth -= 1

    visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = _function

    def visit_If(self, node: ast.If) -> None:
        if _is_type_checking(node.test):
            self._type_only += 1
            for child in node.body:
                self.visit(child)
            self._type_only -= 1
            for child in node.orelse:
                self.visit(child)
        else:
            self.generic_visit(node)

    # --- imports ------------------------------------------------------------------------
    def _add(self, target: str, line: int, string: bool = False) -> None:
        self.found.append(Import(self.module, target, line, self._depth > 0 or string,
                                 self._type_only > 0, string))

    def visit_Call(self, node: ast.Call) -> None:
        func = node.func
        if isinstance(func, ast.Attribute) and func.attr == "getLogger":
            return  # a logger's name is no import
        self.generic_visit(node)

    def visit_Constant(self, node: ast.Constant) -> None:
        """A string naming a module of the package (``module`` or ``module:attr``)."""
        if (isinstance(node.value, str) and node.value.startswith(PACKAGE + ".")
                and node.value not in GROUPS):
            module = node.value.partition(":")[0]
            if module in self.known:
                self._add(module, node.lineno, string=True)

    def visit_JoinedStr(self, node: ast.JoinedStr) -> None:
        """An f-string's leading literal naming a module (``f"lodsprite.x:{name}"``)."""
        head = node.values[0] if node.values else None
        if (isinstance(head, ast.Constant) and isinstance(head.value, str)
                and head.value.startswith(PACKAGE + ".")):
            module = head.value.partition(":")[0]
            if module in self.known and (len(node.values) == 1 or ":" in head.value):
                self._add(module, node.lineno, string=True)
        for value in node.values[1:]:
            self.visit(value)

    def _resolve(self, dotted: str) -> str:
        """The longest known module that ``dotted`` names (an outside name: its top)."""
        if dotted.split(".")[0] != PACKAGE:
            return dotted.split(".")[0]
        parts = dotted.split(".")
        while parts and ".".join(parts) not in self.known:
            parts.pop()
        return ".".join(parts) if parts else PACKAGE

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self._add(self._resolve(alias.name), node.lineno)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        base = node.module or ""
        if node.level:
            here = self.module.split(".")
            if not self.is_package:
                here = here[:-1]
            here = here[: len(here) - (node.level - 1)]
            base = ".".join([*here, base] if base else here)
        for alias in node.names:
            full = f"{base}.{alias.name}"
            if full in self.known:
                self._add(full, node.lineno)
            elif base == PACKAGE and alias.name in self.facade:
                self._add(self.facade[alias.name], node.lineno)
            else:
                self._add(self._resolve(base), node.lineno)


def imports(src: Path = SRC) -> list[Import]:
    """Every import edge of the package (self-imports of the facade left out)."""
    files = module_files(src)
    known = set(files)
    facade = _facade_table(files)
    edges = []
    for name, path in files.items():
        collector = _Collector(name, path.name == "__init__.py", known, facade)
        collector.visit(ast.parse(path.read_text(), filename=str(path)))
        edges += [e for e in collector.found if e.target != e.source]
    return edges


def unit(module: str) -> str:
    """A module's package for the package graph: ``lodsprite.gl.terrain`` -> ``gl``,
    ``lodsprite.api`` -> ``api`` (each top-level module is its own unit)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """The graph's cycles as strongly connected components of two or more nodes
    (Tarjan, iterative), each sorted, the list sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    counter = 0
    nodes = set(graph) | {t for ts in graph.values() for t in ts}
    for root in sorted(nodes):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        top = stack.pop()
                        on_stack.discard(top)
                        comp.append(top)
                        if top == node:
                            break
                    if len(comp) > 1:
                        found.append(sorted(comp))
            elif child not in index:
                index[child] = low[child] = counter
                counter += 1
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph.get(child, ())))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return sorted(found)


def runtime_graph(edges: Iterable[Import], packages: bool = False) -> dict[str, set[str]]:
    """Module (or, with ``packages``, package) graph of the imports that run, lazy ones
    included, inside the package only; the facade ``lodsprite`` itself is no node."""
    return import_graph(edges, packages, type_only=False)


def import_graph(edges: Iterable[Import], packages: bool = False,
                 type_only: bool = True) -> dict[str, set[str]]:
    """:func:`runtime_graph` with the imports under ``TYPE_CHECKING`` too (``type_only``):
    a hint names the module it imports, so a layer's hints point down as its imports do."""
    graph: dict[str, set[str]] = defaultdict(set)
    for e in edges:
        if ((e.type_only and not type_only) or e.target.split(".")[0] != PACKAGE
                or PACKAGE in (e.source, e.target)):
            continue
        a, b = (unit(e.source), unit(e.target)) if packages else (e.source, e.target)
        if a != b:
            graph[a].add(b)
    return dict(graph)


def function_lengths(src: Path = SRC) -> list[tuple[int, str]]:
    """``(lines, 'module:function')`` for every function and method, longest first."""
    out = []
    for name, path in module_files(src).items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                out.append((node.end_lineno - node.lineno + 1, f"{name}:{node.name}"))
    return sorted(out, reverse=True)
