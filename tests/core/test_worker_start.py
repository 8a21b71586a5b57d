"""How worker processes start: forked from the planned parent, or spawned.

:func:`idbench.run.executors.start_method` and what a forked worker leaves to
its parent (:func:`idbench.run.executors.worker._forked`); the progress bar
that lets the command line fork (no refresh thread with ``--jobs`` > 1); a
comparison that gives the same numbers whichever way its workers start.
"""

from __future__ import annotations

import io
import json
import logging
import multiprocessing as mp
import subprocess
import sys
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from idbench.cli.progress import CompareProgress
from idbench.plan.check import plan
from idbench.plan.config import CompareConfig, ConfigError
from idbench.registry.registry import build_registry
from idbench.run import executors
from idbench.run.compare import compare
from idbench.run.session import Session

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
    monkeypatch.setattr(executors.start.threading, "active_count", lambda: 1)
    assert executors.start_method() == "fork"


AUTO = """
import json, sys
from idbench.run import executors
from idbench.plan.config import CompareConfig
from idbench.run.compare import compare
started = []
new = executors.Worker.__init__
def record(self, session=None):
    started.append("fork" if session is not None else "spawn")
    new(self, session)
executors.Worker.__init__ = record
if __name__ == "__main__":
    given = json.loads(sys.argv[1]).items()
    config = {k: tuple(v) if isinstance(v, list) else v for k, v in given}
    runs, _ = compare(CompareConfig(**config), None, jobs=2)
    print(json.dumps({"started": started, "ok": bool((runs.status == "ok").all())}))
"""


def test_a_sweep_from_a_fresh_interpreter_forks_by_default(monkeypatch, tmp_path):
    monkeypatch.delenv(executors.START_METHOD_ENV, raising=False)
    script = tmp_path / "auto.py"
    script.write_text(AUTO)
    done = subprocess.run(
        [sys.executable, str(script), json.dumps(TINY)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    want = "fork" if LINUX else "spawn"
    assert report == {"started": [want, want], "ok": True}


def test_a_bad_start_method_is_one_line_naming_the_allowed(monkeypatch, tmp_path):
    monkeypatch.setenv(executors.START_METHOD_ENV, "thread")
    message = "IDBENCH_START_METHOD='thread': allowed are auto, fork, spawn"
    with pytest.raises(ConfigError, match=message):
        executors.start_method()
    for jobs, timeout in ((2, None), (1, 30.0)):  # a timeout needs workers too
        with pytest.raises(ConfigError, match=message):
            compare(CompareConfig(timeout=timeout), tmp_path / "out", jobs=jobs)
        assert not (tmp_path / "out").exists()  # refused before anything ran


def test_a_registry_built_by_hand_runs_in_this_process_whatever_jobs_says(
    monkeypatch, tmp_path
):
    def no_worker(*args: Any) -> None:
        raise AssertionError("a worker process was started")

    monkeypatch.setattr(executors.Worker, "__init__", no_worker)
    runs, _ = compare(
        CompareConfig(**TINY), tmp_path, jobs=2, registry=build_registry()
    )
    assert len(runs) == 2 and (runs["status"] == "ok").all()


def test_a_worker_started_while_another_thread_runs_is_spawned(monkeypatch):
    monkeypatch.delenv(executors.START_METHOD_ENV, raising=False)
    monkeypatch.setattr(executors.start.threading, "active_count", lambda: 1)
    pool = executors.Pool(1, None, Session(build_registry()))
    try:
        assert pool.workers[0].proc._start_method == ("fork" if LINUX else "spawn")  # type: ignore[attr-defined]
        monkeypatch.setattr(executors.start.threading, "active_count", lambda: 2)
        pool._replace(pool.workers[0])  # as after a worker died mid-sweep
        assert pool.workers[0].proc._start_method == "spawn"  # type: ignore[attr-defined]
    finally:
        pool.close()


def test_a_pool_that_fails_to_start_a_worker_leaves_none_running(monkeypatch):
    made: list[executors.Worker] = []
    new = executors.Pool._new

    def second_fails(self: executors.Pool) -> executors.Worker:
        if made:
            raise OSError("cannot fork: out of memory")
        made.append(new(self))
        return made[-1]

    monkeypatch.setattr(executors.Pool, "_new", second_fails)
    with pytest.raises(OSError, match="cannot fork"):
        executors.Pool(2, None, Session(build_registry()))
    assert len(made) == 1 and not made[0].proc.is_alive()


def test_fork_is_refused_where_the_platform_cannot(monkeypatch):
    monkeypatch.setenv(executors.START_METHOD_ENV, "fork")
    monkeypatch.setattr(executors.start.mp, "get_all_start_methods", lambda: ["spawn"])
    with pytest.raises(ConfigError, match="fork: this platform cannot fork"):
        executors.start_method()


def _report_forked_state(session: Session, out: Any) -> None:
    """In a forked child: take over ``session`` and report what it then has."""
    from threadpoolctl import threadpool_info

    executors.worker._forked(session)
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
            "warnings": warnings.showwarning is logging._showwarning,  # type: ignore[attr-defined]
        }
    )


@pytest.mark.skipif(not LINUX, reason="forks on Linux only")
def test_a_forked_worker_leaves_the_parents_terminal_and_keeps_its_session():
    from threadpoolctl import threadpool_info, threadpool_limits

    ctx = mp.get_context("fork")
    session = Session(build_registry())
    handler = logging.StreamHandler(io.StringIO())  # the parent's, e.g. a bar's
    idb = logging.getLogger("idbench")
    idb.addHandler(handler)
    saved = sys.stdout
    sys.stdout = io.StringIO()  # a progress bar's stand-in for stdout
    logging.captureWarnings(False)  # whatever an earlier test left
    logging.captureWarnings(True)  # as the command line does
    try:
        with threadpool_limits(limits=2):  # the parent's BLAS: 2 threads
            parents = [lib["num_threads"] for lib in threadpool_info()]
            mine, theirs = ctx.Pipe()
            child = ctx.Process(
                target=_report_forked_state, args=(session, theirs), daemon=True
            )
            child.start()
        theirs.close()
        assert mine.poll(60), "the forked child did not report"
        state = mine.recv()
        child.join(30)
    finally:
        if "child" in locals() and child.is_alive():
            child.kill()
        logging.captureWarnings(False)
        sys.stdout = saved
        idb.removeHandler(handler)
    assert child.exitcode == 0
    assert state["handlers"] == []
    assert state["stdout"] and state["stderr"]
    assert state["warnings"]  # handled as the parent does (the CLI hides them)
    assert 2 in parents and state["blas"] and set(state["blas"]) == {1}
    assert state["session"]


def test_a_forked_worker_holds_the_parents_products_and_a_spawned_none(
    monkeypatch,
):
    session = Session(build_registry())
    session._refs["some-data"] = [1.0]  # as remember_reference stores
    sent: list[Any] = []
    monkeypatch.setattr(
        executors.worker, "_send", lambda conn, message: sent.append(message)
    )
    for forked in (True, False) if LINUX else (False,):
        worker = executors.Worker(session if forked else None)
        try:
            worker.give("a run", session.shared())  # type: ignore[arg-type]
            _, new = sent.pop()
            if forked:  # it holds them already: nothing to send
                assert worker.has == {("reference", "some-data")} and new == {}
            else:
                assert worker.has == set(new) == {("reference", "some-data")}
        finally:
            worker.stop()


def test_the_pool_ticks_while_workers_run(monkeypatch):
    monkeypatch.setattr(executors.pool, "TICK_S", 0.01)
    session = Session(build_registry())
    runs = plan(CompareConfig(**TINY), session).runs
    ticks: list[float] = []
    rows = [
        r
        for r, _ in executors.execute_all(
            runs, session, jobs=2, tick=lambda: ticks.append(1)
        )
    ]
    assert [r["status"] for r in rows] == ["ok", "ok"]
    assert len(ticks) >= 2  # at least once a finished run, more while they run


def test_a_tick_that_raises_is_dropped_and_the_sweep_goes_on(monkeypatch, caplog):
    session = Session(build_registry())
    runs = plan(CompareConfig(**TINY), session).runs
    calls: list[int] = []

    def broken() -> None:
        calls.append(1)
        raise BrokenPipeError("stderr is gone")

    rows = [r for r, _ in executors.execute_all(runs, session, jobs=2, tick=broken)]
    assert [r["status"] for r in rows] == ["ok", "ok"]
    assert calls == [1]
    assert "progress display failed" in caplog.text


def test_the_pool_wakes_up_within_most_seconds_when_no_worker_has_news():
    pool = executors.Pool(1, None, Session(build_registry()))
    (worker,) = pool.workers
    worker.spec = "busy, silent"  # type: ignore[assignment]
    try:
        waiting = threading.Thread(target=pool.wait, args=(0.05,), daemon=True)
        waiting.start()
        waiting.join(10)
        assert not waiting.is_alive(), "wait(0.05) blocked with a silent worker"
    finally:
        pool.close()  # ends a wait that did block: the worker's sentinel


def test_tick_redraws_the_bar_of_a_parallel_sweep(tmp_path):
    from rich.console import Console

    bar = CompareProgress([], tmp_path, 2, quiet=False)
    out = io.StringIO()
    bar.console, bar.terminal = Console(file=out, force_terminal=True), True
    with bar:
        drawn = len(out.getvalue())
        bar.tick()
        assert len(out.getvalue()) > drawn


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


TINY = {
    "truth_mesh": "10x2x2",
    "meshes": ("4x1x1",),
    "steps": 3,
    "seeds": 1,
    "estimators": ("rls", "batch-ls"),
}

SMALL = {
    "truth_mesh": "10x2x2",
    "meshes": ("4x1x1",),
    "steps": 3,
    "seeds": 2,
    "estimators": ("rls", "ro-ukf", "batch-ls"),
}


@pytest.mark.skipif(not LINUX, reason="forks on Linux only")
def test_forked_and_spawned_workers_give_the_same_numbers(monkeypatch, tmp_path: Path):
    tables, started = {}, []
    new = executors.Worker.__init__

    def record(self: Any, session: Session | None = None) -> None:
        started.append("fork" if session is not None else "spawn")
        new(self, session)

    monkeypatch.setattr(executors.Worker, "__init__", record)
    # the same kernel and solver in the parent and in every worker, whatever
    # earlier tests of the session chose (they differ in the last bits)
    monkeypatch.setenv("IDBENCH_NUMBA", "0")
    monkeypatch.setenv("IDBENCH_SOLVER", "scipy")
    for method in ("fork", "spawn"):
        monkeypatch.setenv(executors.START_METHOD_ENV, method)
        runs, _ = compare(CompareConfig(**SMALL), tmp_path / method, jobs=2)
        tables[method] = runs.set_index("run_id").sort_index()
        assert started == [method, method]
        started.clear()
    fork, spawn = tables["fork"], tables["spawn"]
    assert len(fork) == 6 and (fork["status"] == "ok").all()
    assert list(fork.index) == list(spawn.index)
    # Forked workers run the models the parent built, spawned ones build their
    # own: each with the kernel and solver its process chose when building
    # (numba or numpy, PARDISO or SuperLU: IDBENCH_NUMBA, IDBENCH_SOLVER and
    # what earlier code in the process did). Those agree to the Newton
    # tolerance, not bitwise, and batch-ls's fit (E_ref) stops at its own
    # tolerance: 5.7e-10 apart after a full test suite. What ran before in a
    # session does not matter (tests/test_isolation.py: bitwise).
    for col in ("E_final", "E_ref", "shape_error_final"):
        np.testing.assert_allclose(fork[col], spawn[col], rtol=1e-9, err_msg=col)
    assert (fork["n_solves"] == spawn["n_solves"]).all()
