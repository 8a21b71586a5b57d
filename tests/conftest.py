"""Shared fixtures: an isolated truth cache and worker start for every test,
a study loader, a plugin installer, a recorder of the runs executed."""

from __future__ import annotations

import importlib.util
import os
import sys
import textwrap
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import pytest

from idbench.registry.registry import AUTOLOAD_ENV

STUDIES = Path(__file__).resolve().parent.parent / "studies"

# The tests live in folders that mirror the packages (core/, fem/, filters/,
# studies/); what they share (toy models, helpers, oracles, plugins) is the
# package support/ here, which they import (``from support.toymodels import
# LinearToy``); a test module never imports another.
_TESTS = Path(__file__).resolve().parent
if str(_TESTS) not in sys.path:
    sys.path.insert(0, str(_TESTS))


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


@pytest.fixture
def install(tmp_path, monkeypatch) -> Iterator[Callable[[str, str], None]]:
    """Install a plugin module under an entry point, here and in child processes.

    ``install(name, source)`` writes module ``idbench_test_<name>`` with the
    (dedented) ``source`` and its distribution metadata into a folder on
    ``sys.path`` and ``PYTHONPATH``, as pip would; plugin autoloading is on.
    """
    site = tmp_path / "site"
    site.mkdir()
    monkeypatch.syspath_prepend(str(site))
    paths = [str(site), os.environ.get("PYTHONPATH", "")]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in paths if p))
    monkeypatch.delenv(AUTOLOAD_ENV, raising=False)

    def add(name: str, source: str) -> None:
        module = f"idbench_test_{name.replace('-', '_')}"
        sys.modules.pop(module, None)  # not another test's module of that name
        added.append(module)
        (site / f"{module}.py").write_text(textwrap.dedent(source))
        info = site / f"{module}-0.1.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(
            f"Metadata-Version: 2.1\nName: {module}\nVersion: 0.1\n"
        )
        (info / "entry_points.txt").write_text(f"[idbench]\n{name} = {module}\n")

    added: list[str] = []
    yield add
    for module in added:  # nor this one imported for the tests after
        sys.modules.pop(module, None)


@pytest.fixture
def counted(monkeypatch) -> list[str]:
    """The run ids :func:`idbench.run.executors.execute` runs (serial sweeps)."""
    import idbench.run.executors

    executed: list[str] = []
    real = idbench.run.executors.execute

    def wrapper(spec, session, phase=None):
        executed.append(spec.run_id)
        return real(spec, session, phase)

    monkeypatch.setattr(idbench.run.executors, "execute", wrapper)
    return executed
