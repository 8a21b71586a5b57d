"""The FE plugin's face: a flat, eager namespace, and no reach into private names."""

from __future__ import annotations

import ast
from pathlib import Path

from support.helpers import run_fresh_python
from support.namespace import private_reaches

import idbench_fem

PLUGINS = Path(idbench_fem.__file__).resolve().parent.parent


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
    run_fresh_python(code, timeout=120)


def test_no_plugin_module_has_a_module_getattr():
    for path in sorted((PLUGINS / "idbench_fem").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
        assert "__getattr__" not in names, path
