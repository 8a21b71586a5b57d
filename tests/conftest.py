"""Shared fixtures: an isolated truth cache for every test, a study loader."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

STUDIES = Path(__file__).resolve().parent.parent / "studies"


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Never read or write the user's truth cache from a test."""
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "c"))


@pytest.fixture
def study(monkeypatch) -> Callable[[str], ModuleType]:
    """Load ``studies/<name>.py`` (scripts, not a package) as a module."""
    monkeypatch.syspath_prepend(str(STUDIES))  # as when run: their _cli helper

    def load(name: str) -> ModuleType:
        spec = importlib.util.spec_from_file_location(name, STUDIES / f"{name}.py")
        assert spec is not None and spec.loader is not None, name
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load
