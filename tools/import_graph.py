"""The import graph of the project's packages, and its circles.

    python tools/import_graph.py            # the circles (strongly connected modules), exit 1 if any
    python tools/import_graph.py --edges    # every edge, ``a -> b (line, kind)``

An edge ``a -> b`` is an ``import`` or ``from ... import`` of a project module ``b`` anywhere in
``a``'s source: at the top (kind ``top``), inside a function or class body (``lazy``: run when
called, still a circle of dependencies), or under ``if TYPE_CHECKING:`` (``typing``: never run,
left out of the circles unless ``--typing``). ``from p import x`` counts as an import of ``p.x``
when that is a module, else of ``p``; importing ``p.q`` also imports the package ``p``
(``p/__init__.py``), which is an edge of its own when ``p/__init__.py`` imports anything.
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path
from typing import Iterator, NamedTuple

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("ahrm_stack",)


class Edge(NamedTuple):
    source: str
    target: str
    line: int
    kind: str  # "top", "lazy" or "typing"


def modules(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, Path]:
    """Dotted module name -> source file, for every ``.py`` under ``packages`` (vendored code
    under a ``vendor`` folder left out)."""
    found = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if "vendor" in parts:
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module) -> Iterator[tuple[ast.Import | ast.ImportFrom, str]]:
    """Every import statement of ``tree`` with its kind."""

    def visit(node: ast.AST, kind: str) -> Iterator[tuple[ast.Import | ast.ImportFrom, str]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                yield child, kind
            elif isinstance(child, ast.If) and _is_type_checking(child.test):
                for statement in child.body:
                    yield from visit(ast.Module(body=[statement], type_ignores=[]), "typing")
                for statement in child.orelse:
                    yield from visit(ast.Module(body=[statement], type_ignores=[]), kind)
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                yield from visit(child, "typing" if kind == "typing" else "lazy")
            else:
                yield from visit(child, kind)

    yield from visit(tree, "top")


def edges(known: dict[str, Path]) -> list[Edge]:
    """The edges between the modules of ``known`` (from :func:`modules`)."""
    found = []
    for name, path in known.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = ast.parse(path.read_text(), str(path))
        for node, kind in _imports(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                for alias in node.names:
                    full = f"{base}.{alias.name}"
                    targets.append(full if full in known else base)
            for target in targets:
                # the deepest project module named by the import (``a.b.c`` of a module ``a.b``)
                while target and target not in known:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    found.append(Edge(name, target, node.lineno, kind))
    return found


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def connect(node: str) -> None:
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                connect(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))
    for node in sorted(graph):
        if node not in index:
            connect(node)
    return sorted(found)


def graph_of(found: list[Edge], known: dict[str, Path], typing: bool = False) -> dict[str, set[str]]:
    """Adjacency sets; importing ``p.q`` runs ``p/__init__.py`` first, so it is an edge to ``p``
    too (kept only when ``p`` imports something, the only way it can close a circle)."""
    graph: dict[str, set[str]] = {name: set() for name in known}
    for edge in found:
        if edge.kind == "typing" and not typing:
            continue
        graph[edge.source].add(edge.target)
    for name in list(graph):
        parent = name.rpartition(".")[0]
        for target in list(graph[name]):
            ancestor = target.rpartition(".")[0]
            while ancestor and ancestor != name and ancestor in known and not name.startswith(ancestor + "."):
                if graph[ancestor]:
                    graph[name].add(ancestor)
                ancestor = ancestor.rpartition(".")[0]
        del parent
    return graph


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--edges", action="store_true", help="print every edge")
    parser.add_argument("--typing", action="store_true", help="count TYPE_CHECKING imports too")
    args = parser.parse_args(argv)
    known = modules()
    found = edges(known)
    if args.edges:
        for edge in found:
            print(f"{edge.source} -> {edge.target} (line {edge.line}, {edge.kind})")
    loops = circles(graph_of(found, known, args.typing))
    for loop in loops:
        members = set(loop)
        print(f"circle of {len(loop)} modules: {', '.join(loop)}")
        for edge in found:
            if edge.source in members and edge.target in members and (args.typing or edge.kind != "typing"):
                print(f"    {edge.source} -> {edge.target} (line {edge.line}, {edge.kind})")
    if not loops:
        print(f"no import circle among {len(known)} modules")
    return 1 if loops else 0


if __name__ == "__main__":
    sys.exit(main())
