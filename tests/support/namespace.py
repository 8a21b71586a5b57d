"""Reaches into private names, found on a plugin package's syntax trees."""

from __future__ import annotations

import ast
from pathlib import Path


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_reaches(package: Path) -> list[str]:
    """Imports of private names or modules, and ``obj._name`` on another object.

    ``self``, ``cls`` and ``super()`` are the object's own; so is the other
    instance a ``__copy__`` builds. ``os._exit`` is the os module's public API.
    """
    found = []
    for path in sorted(package.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        own = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and node.name == "__copy__":
                own.update(id(n) for n in ast.walk(node))
        for node in ast.walk(tree):
            where = f"{path.relative_to(package.parent)}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [a.name for a in node.names]
                if any(map(_private, node.module.split("."))) or any(
                    map(_private, names)
                ):
                    found.append(f"{where} from {node.module} import {names}")
            elif isinstance(node, ast.Attribute) and _private(node.attr):
                value = node.value
                if isinstance(value, ast.Name) and value.id in ("self", "cls"):
                    continue
                if isinstance(value, ast.Call) and ast.unparse(value.func) == "super":
                    continue
                if id(node) in own or ast.unparse(node) == "os._exit":
                    continue
                found.append(f"{where} {ast.unparse(node)}")
    return found
