"""The FE plugin's face: a flat, eager namespace, and no reach into private names."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import idbench_fem

PLUGINS = Path(idbench_fem.__file__).resolve().parent.parent


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
            where = f"{path.relative_to(PLUGINS)}:{getattr(node, 'lineno', 0)}"
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


def test_no_module_reaches_into_another_objects_private_names():
    assert private_reaches(PLUGINS / "idbench_fem") == []


def test_the_public_names_are_imported_with_the_package():
    code = (
        "import sys, idbench_fem\n"
        "assert not hasattr(idbench_fem, '__getattr__')\n"
        "missing = [n for n in idbench_fem.__all__ if n not in vars(idbench_fem)]\n"
        "assert not missing, missing\n"
        "assert 'idbench_fem.models.solid' in sys.modules\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr


def test_no_plugin_module_has_a_module_getattr():
    for path in sorted((PLUGINS / "idbench_fem").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
        assert "__getattr__" not in names, path
