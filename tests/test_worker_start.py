"""How worker processes start: forked from the planned parent, or spawned.

:func:`idbench.executors.start_method` and what a forked worker leaves to
its parent (:func:`idbench.executors._forked`); the progress bar that lets the
command line fork (no refresh thread with ``--jobs`` > 1); a comparison that
gives the same numbers whichever way its workers start.
"""

from __future__ import annotations

import io
import logging
import multiprocessing as mp
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from idbench import executors
from idbench.config import CompareConfig, ConfigError
from idbench.plugins import build_registry
from idbench.progress import CompareProgress
from idbench.session import Session
from idbench.sweep import compare

LINUX = sys.platform.startswith("linux")


@pytest.fixture
def another_thread() -> Iterator[None]:
    """A second Python thread, alive for the test."""
    stop = threading.Event()
    thread = threading.Thread(target=stop.wait, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(5)


@pytest.mark.parametrize("value", ["fork", "spawn", " Spawn "])
def test_the_environment_chooses_the_start_method(monkeypatch, value):
    monkeypatch.setenv(executors.START_METHOD_ENV, value)
    assert executors.start_method() == value.strip().lower()


@pytest.mark.parametrize("value", ["", "auto"])
def test_auto_forks_only_a_single_threaded_linux_process(
    monkeypatch, value, another_thread
):
    monkeypatch.setenv(executors.START_METHOD_ENV, value)
    assert executors.start_method() == "spawn"  # another thread is alive


@pytest.mark.skipif(not LINUX, reason="forks on Linux only")
def test_auto_forks_when_this_process_runs_one_thread(monkeypatch):
    monkeypatch.delenv(executors.START_METHOD_ENV, raising=False)
    monkeypatch.setattr(executors.threading, "active_count", lambda: 1)
    assert executors.start_method() == "fork"


def test_a_bad_start_method_is_one_line_naming_the_allowed(monkeypatch, tmp_path):
    monkeypatch.setenv(executors.START_METHOD_ENV, "thread")
    message = "IDBENCH_START_METHOD='thread': allowed are auto, fork, spawn"
    with pytest.raises(ConfigError, match=message):
        executors.start_method()
    with pytest.raises(ConfigError, match=message):
        compare(CompareConfig(), tmp_path / "out", jobs=2)
    assert not (tmp_path / "out").exists()  # refused before anything ran


def _report_forked_state(session: Session, out: Any) -> None:
    """In a forked child: take over ``session`` and report what it then has."""
    from threadpoolctl import threadpool_info

    executors._forked(session)
    loggers = [logging.getLogger(), logging.getLogger("idbench")]
    out.send(
        {
            "handlers": [
                type(h).__name__
                for lg in loggers
                for h in lg.handlers
                if not isinstance(h, logging.NullHandler)
            ],
            "stdout": sys.stdout is sys.__stdout__,
            "stderr": sys.stderr is sys.__stderr__,
            "blas": [lib["num_threads"] for lib in threadpool_info()],
            "session": executors.worker_session() is session,
            "spares": executors._spares(),
        }
    )


@pytest.mark.skipif(not LINUX, reason="forks on Linux only")
def test_a_forked_worker_leaves_the_parents_terminal_and_keeps_its_session():
    ctx = mp.get_context("fork")
    session = Session(build_registry())
    handler = logging.StreamHandler(io.StringIO())  # the parent's, e.g. a bar's
    idb = logging.getLogger("idbench")
    idb.addHandler(handler)
    saved = sys.stdout
    sys.stdout = io.StringIO()  # a progress bar's stand-in for stdout
    try:
        mine, theirs = ctx.Pipe()
        child = ctx.Process(target=_report_forked_state, args=(session, theirs))
        child.start()
        state = mine.recv()
        child.join(30)
    finally:
        sys.stdout = saved
        idb.removeHandler(handler)
    assert child.exitcode == 0
    assert state["handlers"] == []
    assert state["stdout"] and state["stderr"]
    assert state["blas"] and set(state["blas"]) == {1}
    assert state["session"] and state["spares"] == []


def test_a_forked_worker_holds_the_parents_products_and_a_spawned_none(
    monkeypatch,
):
    session = Session(build_registry())
    session._refs["some-data"] = [1.0]  # as remember_reference stores
    for method, expect in (("fork", {("reference", "some-data")}), ("spawn", set())):
        if method == "fork" and not LINUX:
            continue
        worker = executors._Worker(executors._context(method), session)
        try:
            assert worker.has == expect
        finally:
            worker.stop()


@pytest.mark.parametrize("jobs,threads", [(1, 1), (2, 0)])
def test_the_progress_bar_runs_a_thread_only_for_a_serial_sweep(
    tmp_path, jobs, threads
):
    bar = CompareProgress([], tmp_path, jobs, quiet=False)
    from rich.console import Console

    out = io.StringIO()
    bar.console, bar.terminal = Console(file=out, force_terminal=True), True
    before = threading.active_count()
    with bar:
        assert threading.active_count() - before == threads
        bar(1, 1, {"run_id": "a", "estimator": "rls", "status": "ok"})
        if not threads:  # drawn at once, not at the thread's next refresh
            assert "1/1" in out.getvalue()
    assert "1/1" in out.getvalue()


SMALL = {
    "truth_mesh": "10x2x2",
    "meshes": ("4x1x1",),
    "steps": 3,
    "seeds": 2,
    "estimators": ("rls", "ro-ukf", "batch-ls"),
}


@pytest.mark.skipif(not LINUX, reason="forks on Linux only")
def test_forked_and_spawned_workers_give_the_same_numbers(monkeypatch, tmp_path: Path):
    tables = {}
    for method in ("fork", "spawn"):
        monkeypatch.setenv(executors.START_METHOD_ENV, method)
        runs, _ = compare(CompareConfig(**SMALL), tmp_path / method, jobs=2)
        tables[method] = runs.set_index("run_id").sort_index()
    fork, spawn = tables["fork"], tables["spawn"]
    assert len(fork) == 6 and (fork["status"] == "ok").all()
    assert list(fork.index) == list(spawn.index)
    assert (fork["E_final"] == spawn["E_final"]).all()
    assert (fork["E_ref"] == spawn["E_ref"]).all()
