"""The core names no plugin and no physics.

Every string constant (docstrings excepted), name, attribute and argument in
every module of ``idbench/`` is scanned for the names the built-in plugins
register (models, scenarios, estimators, their default meshes) and for words
that would assume the beam or elasticity. Defaults must come from what plugins register.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import idbench

CORE = Path(idbench.__file__).resolve().parent
PHYSICS = ("E_true", "nu", "tip", "tip_x", "traction", "E_regions", "Young",
           "Poisson", "young", "poisson", "true_factors", "cantilever")  # fmt: skip


def builtin_names() -> set[str]:
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    names: set[str] = set()
    for table in (reg.models, reg.scenarios, reg.estimators):
        names |= {n for n, e in table.items() if e.plugin in ("fem", "filters")}
    for entry in reg.models.values():
        d = entry.defaults
        if d is not None:
            names |= {d.truth_mesh, *d.meshes, *d.scenarios}
            names |= {str(v) for v in d.quick.get("meshes", ())}
            names.add(str(d.quick.get("truth_mesh", "")))
    names.discard("")
    return names


def _docstrings(tree: ast.AST) -> set[int]:
    """Docstrings, and the stylesheet (``STYLE = "..."``: CSS words such as
    ``solid`` are not model names)."""
    ids = set()
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Assign)
            and [getattr(t, "id", None) for t in node.targets] == ["STYLE"]
            and isinstance(node.value, ast.Constant)
        ):
            ids.add(id(node.value))
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr):
                value = body[0].value
                if isinstance(value, ast.Constant) and isinstance(value.value, str):
                    ids.add(id(value))
    return ids


def words_in(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every string constant and identifier of ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if id(node) not in skip:
                found.append((node.lineno, node.value))
        elif isinstance(node, ast.Name):
            found.append((node.lineno, node.id))
        elif isinstance(node, ast.Attribute):
            found.append((node.lineno, node.attr))
        elif isinstance(node, ast.arg):
            found.append((node.lineno, node.arg))
        elif isinstance(node, ast.keyword) and node.arg:
            found.append((node.lineno, node.arg))
    return found


def offences(path: Path, banned: set[str]) -> list[str]:
    patterns = {b: re.compile(rf"(?<![\w-]){re.escape(b)}(?![\w-])") for b in banned}
    out = []
    for line, text in words_in(path):
        for b, pattern in patterns.items():
            if pattern.search(text):
                out.append(f"{path.name}:{line}: {b!r} in {text!r}")
    return out


def test_the_scan_finds_a_planted_name(tmp_path):
    planted = tmp_path / "planted.py"
    planted.write_text(
        '"""bend-y in a docstring is fine."""\n'
        'X = {"model": "svk-beam"}\n'
        "def f(nu): return nu\n"
    )
    found = offences(planted, {"svk-beam", "bend-y", "nu"})
    assert any("'svk-beam'" in f for f in found)
    assert any("'nu'" in f for f in found)
    assert not any("bend-y" in f for f in found)


def test_builtin_names_are_known():
    names = builtin_names()
    assert {"svk-beam", "bend-y", "ro-ukf", "batch-ls", "80x11x11"} <= names


@pytest.mark.parametrize(
    "path", sorted(CORE.rglob("*.py")), ids=lambda p: str(p.relative_to(CORE))
)
def test_core_module_names_no_plugin_and_no_physics(path):
    banned = builtin_names() | set(PHYSICS)
    found = offences(path, banned)
    assert not found, "\n".join(found)


def test_the_command_line_names_no_plugin_command():
    """Plugin commands (``calibrate``, ``mesh``, ``check``) come from the registry.

    Their names are everyday words elsewhere in the core (a mesh, a check), so
    only the command line is held to it: no string of ``idbench/cli/`` is a
    plugin's command name, unless it is a field of a run (``mesh``).
    """
    import dataclasses

    from idbench.plan.runspec import RunSpec

    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    commands = {n for n, e in reg.commands.items() if e.plugin in ("fem", "filters")}
    assert commands, "the built-in plugins register commands"
    commands -= {f.name for f in dataclasses.fields(RunSpec)}  # a run's mesh
    found = [
        f"{path.name}:{node.lineno}: {node.value!r}"
        for path in sorted((CORE / "cli").glob("*.py"))
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        if isinstance(node, ast.Constant) and node.value in commands
    ]
    assert not found, "\n".join(found)

