"""The package's own import graph, for the workflow's rerun triggers.

A workflow rule calls one function of a module; its result can change whenever that
module or any package module it imports (transitively) changes. :func:`module_closure`
returns those source files, read statically from the sources with :mod:`ast` (every
``import`` statement anywhere in a module counts, absolute or relative of any depth), so
the Snakefile can declare them as the rule's ``code`` input without importing the
package. Importing a module also runs the ``__init__.py`` of every package above it, so
those count too. Standard library only: the Snakefile loads this file by its path.
"""
from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

PACKAGE = "cvsim6"


@lru_cache(maxsize=None)
def _module_names(root: Path) -> dict[str, Path]:
    """``{dotted name relative to the package: file}``; a package is named by its folder
    (``"nets"`` -> ``nets/__init__.py``), the top package by ``""``. Read once per process:
    the Snakefile asks for it once per rule."""
    names = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def _parents(name: str) -> list[str]:
    """The packages whose ``__init__`` runs before module ``name``: ``"a.b.c"`` -> ``["", "a", "a.b"]``."""
    parts = name.split(".") if name else []
    return [".".join(parts[:i]) for i in range(len(parts))]


def _resolve(target: str, modules: dict[str, Path]) -> str | None:
    """The module ``target`` (dotted, relative to the package) or, when it is an attribute of
    a module rather than a module, the module that holds it; ``None`` outside the package."""
    while target not in modules:
        if not target:
            return None
        target = target.rpartition(".")[0]
    return target


def _imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Package modules that the module ``name`` (at ``path``) imports."""
    is_package = path.name == "__init__.py"
    here = name.split(".") if name else []
    package = here if is_package else here[:-1]
    found: set[str] = set()
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            bases = [alias.name for alias in node.names]
            found.update(b.split(".", 1)[1] if "." in b else "" for b in bases if b.split(".")[0] == PACKAGE)
            continue
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:  # from .x import y, from ..x import y, from . import y
            up = node.level - 1
            if up > len(package):
                continue
            base = ".".join(package[:len(package) - up] + ([node.module] if node.module else []))
        elif node.module and node.module.split(".")[0] == PACKAGE:
            base = node.module.partition(".")[2]
        else:
            continue
        found.add(base)
        for alias in node.names:  # ``from pkg import module`` imports the module too
            candidate = f"{base}.{alias.name}" if base else alias.name
            if candidate in modules:
                found.add(candidate)
    resolved = {_resolve(t, modules) for t in found}
    return {m for m in resolved if m is not None and m != name}


@lru_cache(maxsize=None)
def import_graph(package_dir: str) -> dict[str, frozenset[str]]:
    """``{module: modules whose code runs when it is imported}`` for every module of
    ``package_dir`` (dotted names relative to the package, ``""`` for its ``__init__``):
    the modules it imports and the packages above it."""
    root = Path(package_dir)
    modules = _module_names(root)
    return {name: frozenset(_imported(name, path, modules) | (set(_parents(name)) - {name}))
            for name, path in modules.items()}


def module_closure(module: str, package_dir: str) -> list[str]:
    """Source files of ``module`` (``"studies.structural"`` or ``"cvsim6.studies.structural"``)
    and of every package module it imports, transitively, with the ``__init__.py`` of each
    package on the way; sorted paths under ``package_dir``."""
    name = module.partition(".")[2] if module.startswith(PACKAGE + ".") else module
    graph = import_graph(str(package_dir))
    if name not in graph:
        raise ValueError(f"{module!r} is not a module of {package_dir} ({', '.join(sorted(graph))})")
    modules = _module_names(Path(package_dir))
    seen, todo = set(), [name]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(graph[m] - seen)
    return sorted(str(modules[m]) for m in seen)
