"""Shared fixtures: an isolated truth cache and worker start for every test,
a study loader."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import pytest

STUDIES = Path(__file__).resolve().parent.parent / "studies"


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Never read or write the user's truth cache from a test."""
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "c"))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests marked ``dask`` last, in their order: a Dask client leaves
    threads in this process (its event loop, its offload executor), and a
    sweep forked from a process with other threads may inherit a held lock."""
    dask = [item for item in items if item.get_closest_marker("dask")]
    items[:] = [item for item in items if not item.get_closest_marker("dask")] + dask


@pytest.fixture(autouse=True, scope="session")
def _forked_workers() -> Iterator[None]:
    """Worker processes forked, as a user's sweep on Linux starts them.

    The default (``auto``) would fork or spawn depending on the threads that
    earlier tests left running, so which way the pool tests go would depend
    on their order. Session-wide, so module fixtures that run sweeps see it
    too. Tests of spawned workers and of ``auto`` set
    ``IDBENCH_START_METHOD`` themselves (``tests/test_worker_start.py`` runs
    ``auto`` in a fresh interpreter). Tests marked ``dask`` run last (see
    :func:`pytest_collection_modifyitems`), so the others fork from a process
    that runs one thread.
    """
    with pytest.MonkeyPatch.context() as mp:
        if sys.platform.startswith("linux"):
            mp.setenv("IDBENCH_START_METHOD", "fork")
        yield


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
