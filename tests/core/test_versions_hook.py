"""Plugins report the versions their results depend on; the core names none."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import idbench
from idbench.run.compare import manifest


class Reports:
    """A plugin that reports one package's version."""

    @idbench.hookimpl
    def register_versions(self, register):
        register("libfoo", "1.2.3")


class ReportsBadly:
    """A plugin that reports a version that is no string."""

    @idbench.hookimpl
    def register_versions(self, register):
        register("libbar", 7)


def test_reported_versions_reach_the_manifest_of_the_plugins_used() -> None:
    pm = idbench.get_plugin_manager(autoload=False)
    pm.register(Reports(), name="reports")
    reg = idbench.build_registry(pm)
    assert reg.packages["reports"] == {"libfoo": "1.2.3"}
    used = manifest({"reports": ""}, reg)["versions"]
    assert used["libfoo"] == "1.2.3"
    assert used["idbench"] == idbench.__version__
    assert "libfoo" not in manifest({}, reg)["versions"]  # not used, not recorded


def test_a_version_that_is_no_string_withdraws_the_plugin_naming_it() -> None:
    pm = idbench.get_plugin_manager(autoload=False)
    pm.register(ReportsBadly(), name="badly")
    reg = idbench.build_registry(pm)
    assert "badly" in reg.errors
    assert "register_versions version 7" in reg.errors["badly"]
    assert "badly" not in reg.packages


def test_builtin_plugins_report_their_libraries() -> None:
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    reported = {p for packages in reg.packages.values() for p in packages}
    assert {"scikit-fem", "filterpy"} <= reported


def _strings(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
            and isinstance(n.value, str)}  # fmt: skip


@pytest.mark.parametrize("package", ["scikit-fem", "filterpy", "pypardiso"])
def test_the_core_names_no_plugin_library(package: str) -> None:
    core = Path(idbench.__file__).parent
    named = [p.relative_to(core) for p in core.rglob("*.py") if package in _strings(p)]
    assert not named, f"{package!r} named in {named}"
