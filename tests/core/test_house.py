"""House rules, checked on the source: interfaces, not probes; tests share support.

- The core never looks a member up by name (``hasattr``, ``getattr`` with a
  default) outside :mod:`idbench.core.capabilities`, which declares every
  optional member; the exceptions are listed below, each with its reason.
- No ``__getattr__`` proxy in the core: wrappers delegate explicitly
  (:class:`idbench.core.view.ModelView`).
- No core module imports a private name of another, and none but the command
  line imports the flat face ``idbench`` (the flat face imports the rooms).
- No test module imports another: what tests share is in ``tests/support``
  or in a ``conftest.py``.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CORE = ROOT / "idbench"
TESTS = ROOT / "tests"

PROBES_ALLOWED = {
    ("store/lock.py", 'hasattr(os, "register_at_fork")'): "a stdlib feature test",
    ("store/lock.py", 'getattr(os, "O_NOFOLLOW", 0)'): "a stdlib feature test",
    ("run/harness.py", 'hasattr(signal, "setitimer")'): "a stdlib feature test",
    ("run/executors/worker.py", 'getattr(_LOCAL, "session", None)'): "thread-local",
    ("run/executors/worker.py", 'getattr(_LOCAL, "spares", None)'): "thread-local",
    ("run/executors/dask.py", 'getattr(client, "status", "running")'):
        "a Dask client's state (Dask's attribute, not one of our protocols)",
    ("store/results.py", 'getattr(self, "_open", False)'):
        "its own field, read by close() before __init__ may have set it",
    ("cli/commands.py", 'getattr(args, "verbose", 0)'):
        "argparse: an option of some subcommands only",
    ("cli/parser.py", 'getattr(args, "model_options", None)'):
        "argparse: an option of some subcommands only",
    ("cli/parser.py", 'getattr(args, "observe_options", None)'):
        "argparse: an option of some subcommands only",
}  # fmt: skip
"""(file under idbench/, the call's text) -> why it may look a member up by name."""

PENDING: set[tuple[str, str]] = set()
"""Probes being changed on another branch: delete each entry once fixed."""


def modules(folder: Path) -> Iterator[tuple[str, ast.Module, str]]:
    """(path relative to ``folder``, its syntax tree, its text) of each module."""
    for path in sorted(folder.rglob("*.py")):
        text = path.read_text()
        yield path.relative_to(folder).as_posix(), ast.parse(text), text


def imports(tree: ast.Module) -> Iterator[tuple[int, str, list[str]]]:
    """(line, module, names) of each import; ``import a.b`` gives ("a.b", [])."""
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            module = "." * node.level + (node.module or "")
            yield node.lineno, module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, []


# --- the rules: each gives what a module breaks ---------------------------------


def probes(rel: str, tree: ast.Module, text: str) -> list[str]:
    """Each ``hasattr(...)`` and ``getattr(obj, name, default)`` not allowed."""
    if rel == "core/capabilities.py":
        return []
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            by_name = node.func.id == "hasattr"
            with_default = node.func.id == "getattr" and len(node.args) == 3
            call = ast.get_source_segment(text, node) or node.func.id
            known = (rel, call) in PROBES_ALLOWED or (rel, call) in PENDING
            if (by_name or with_default) and not known:
                out.append(f"idbench/{rel}:{node.lineno}: {call}")
    return out


def proxies(rel: str, tree: ast.Module, text: str) -> list[str]:
    """Each ``def __getattr__`` (a module's or a class's)."""
    return [
        f"idbench/{rel}:{node.lineno}"
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.name == "__getattr__"
        and (rel, "def __getattr__") not in PENDING
    ]


def private_imports(rel: str, tree: ast.Module, text: str) -> list[str]:
    """Each import of a private name or from a private module."""
    return [
        f"idbench/{rel}:{line}: {statement}"
        for line, module, names in imports(tree)
        for name in names + module.split(".")
        if name.startswith("_") and not name.startswith("__")
        for statement in [f"from {module} import {name}"]
        if (rel, statement) not in PENDING
    ]


def flat_face_imports(rel: str, tree: ast.Module, text: str) -> list[str]:
    """Each import of the flat face ``idbench``, outside it and the command line."""
    if rel == "__init__.py" or rel.startswith("cli/"):
        return []
    return [f"idbench/{rel}:{line}" for line, module, _ in imports(tree)
            if module == "idbench"]  # fmt: skip


def imports_of_tests(rel: str, tree: ast.Module, text: str) -> list[str]:
    """Each import of a test module, a conftest or the ``tests`` folder."""
    out = []
    for line, module, names in imports(tree):
        parts = [p for p in module.split(".") if p]
        if (
            parts[:1] == ["tests"]
            or "conftest" in parts + names
            or any(p.startswith("test_") for p in parts + names)
        ):
            out.append(f"tests/{rel}:{line}: {module}")
    return out


def broken(rule: Callable[[str, ast.Module, str], list[str]], folder: Path) -> str:
    return "; ".join(v for m in modules(folder) for v in rule(*m))


def test_the_core_looks_members_up_in_capabilities_only() -> None:
    found = broken(probes, CORE)
    assert not found, (
        "ask idbench.core.capabilities (declare the member there) instead: " + found
    )


def test_the_core_has_no_getattr_proxy() -> None:
    found = broken(proxies, CORE)
    assert not found, f"delegate explicitly (idbench.core.view.ModelView): {found}"


def test_no_core_module_imports_a_private_name_of_another() -> None:
    found = broken(private_imports, CORE)
    assert not found, f"make it public or keep it in its module: {found}"


def test_only_the_command_line_imports_the_flat_face() -> None:
    found = broken(flat_face_imports, CORE)
    assert not found, f"import from the room that defines the name: {found}"


def test_no_test_module_imports_another() -> None:
    found = broken(imports_of_tests, TESTS)
    assert not found, f"share it through tests/support or a conftest.py: {found}"


@pytest.mark.parametrize(
    ("source", "rule"),
    [
        ('x = getattr(model, "volume", None)\n', probes),
        ("ok = hasattr(model, name)\n", probes),
        ("class P:\n    def __getattr__(self, name):\n        return 1\n", proxies),
        ("def __getattr__(name):\n    return 1\n", proxies),
        ("from idbench.core.settings import _ask\n", private_imports),
        ("from idbench.run import _private\n", private_imports),
        ("from idbench import Filter\n", flat_face_imports),
        ("import idbench\n", flat_face_imports),
        ("from test_beam import beam\n", imports_of_tests),
        ("from core.test_plugins import pm\n", imports_of_tests),
        ("from tests.support import helpers\n", imports_of_tests),
        ("from . import test_beam\n", imports_of_tests),
    ],
)
def test_each_rule_catches_what_it_forbids(
    source: str, rule: Callable[[str, ast.Module, str], list[str]]
) -> None:
    assert rule("somewhere/module.py", ast.parse(source), source)
    fine = "from idbench.core.capabilities import member\nx = getattr(a, name)\n"
    assert not rule("somewhere/module.py", ast.parse(fine), fine)
