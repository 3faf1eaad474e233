"""The package's own import graph, for the workflow's rerun triggers.

A workflow rule calls one function of a module; its result can change whenever that
module or any package module it imports (transitively) changes. :func:`module_closure`
returns those source files, read statically from the sources with :mod:`ast` (every
``import`` statement anywhere in a module counts), so the Snakefile can declare them as
the rule's ``code`` input without importing the package. Standard library only.
"""
from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

PACKAGE = "cvsim6"


def _imported_modules(path: Path) -> set[str]:
    """Package modules (short names) that the module at ``path`` imports."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1 and node.module:  # from .x import y / from .x.y import z
                found.add(node.module.split(".")[0])
            elif node.level == 1:  # from . import x, y
                found.update(alias.name for alias in node.names)
            elif node.level == 0 and node.module and node.module.split(".")[0] == PACKAGE:
                parts = node.module.split(".")
                if len(parts) > 1:  # from cvsim6.x import y
                    found.add(parts[1])
                else:  # from cvsim6 import x
                    found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == PACKAGE and len(parts) > 1:
                    found.add(parts[1])
    return found


@lru_cache(maxsize=None)
def import_graph(package_dir: str) -> dict[str, frozenset[str]]:
    """``{module: modules it imports}`` for every ``*.py`` of ``package_dir`` (short names;
    ``__init__`` included, names that are not modules of the package, e.g. ``__version__``,
    dropped)."""
    root = Path(package_dir)
    modules = {p.stem for p in root.glob("*.py")}
    return {p.stem: frozenset(m for m in _imported_modules(p) if m in modules and m != p.stem)
            for p in sorted(root.glob("*.py"))}


def module_closure(module: str, package_dir: str) -> list[str]:
    """Source files of ``module`` (e.g. ``"structural_study"`` or ``"cvsim6.structural_study"``)
    and of every package module it imports, transitively, plus the package's
    ``__init__.py`` (always executed on import); sorted paths under ``package_dir``."""
    name = module.split(".")[-1] if module.startswith(PACKAGE + ".") else module
    graph = import_graph(str(package_dir))
    if name not in graph:
        raise ValueError(f"{module!r} is not a module of {package_dir} ({', '.join(sorted(graph))})")
    seen, todo = {"__init__"}, [name]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(graph[m] - seen)
    return sorted(str(Path(package_dir) / f"{m}.py") for m in seen)
