"""One writer per output folder .

A second process that opens a folder another one writes is refused, naming
the holder, or waits for it (``--wait``); the lock goes with its holder,
killed or not, and forked workers do not keep it; opening a store removes
only the temporary files of writers that are gone. Every test is
deterministic: the holder is a subprocess that holds until the test closes
its stdin, and the waiter says it waits before it blocks.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from idbench.cli.commands import main
from idbench.store.files import temporary_prefix
from idbench.store.lock import FolderBusy, acquire, release
from idbench.store.results import ResultStore

TINY = ["--truth-mesh", "12x3x3", "--meshes", "4x1x1", "--steps", "5", "--seeds",
        "1", "--estimators", "rls"]  # fmt: skip

HOLDER = textwrap.dedent(
    """
    import sys
    from idbench.store.results import ResultStore
    store = ResultStore(sys.argv[1], {"holder": 1}, {})
    print("held", flush=True)
    sys.stdin.read()  # until the test closes our stdin
    store.discard_if_unused()  # leave the folder to the next one's settings
    store.close()
    """
)


def _python(code: str, *args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


@pytest.fixture
def spawn():
    """Start ``python -c CODE ARGS...`` (:func:`_python`); killed and reaped after."""
    procs = []

    def start(code: str, *args: str) -> subprocess.Popen:
        procs.append(_python(code, *args))
        return procs[-1]

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


@pytest.fixture
def holder(spawn):
    """A process that opened a folder and holds it until released."""

    def start(folder: Path) -> subprocess.Popen:
        proc = spawn(HOLDER, str(folder))
        assert proc.stdout.readline() == "held\n", proc.stderr.read()
        return proc

    return start


def _release(proc: subprocess.Popen) -> None:
    proc.stdin.close()
    assert proc.wait() == 0, proc.stderr.read()


def test_a_second_store_is_refused_naming_the_holder(tmp_path, holder):
    out = tmp_path / "out"
    proc = holder(out)
    with pytest.raises(FolderBusy) as err:
        ResultStore(out, {"holder": 1}, {})
    text = str(err.value)
    assert f"pid {proc.pid} on host {socket.gethostname()} since " in text
    assert "--wait" in text and "\n" not in text
    _release(proc)
    ResultStore(out, {"holder": 1}, {}).close()  # free again


def test_a_second_compare_is_refused_in_one_line(tmp_path, holder, capsys):
    out = tmp_path / "out"
    proc = holder(out)
    assert main(["compare", *TINY, "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"in use by pid {proc.pid} on host {socket.gethostname()}" in err
    assert not (out / "runs.parquet").exists()
    _release(proc)


def test_report_is_refused_while_a_compare_writes(tmp_path, spawn, capsys):
    out = tmp_path / "out"
    assert main(["compare", *TINY, "--out", str(out), "-q"]) == 0
    writer = spawn(
        "import sys; from idbench.store.lock import acquire; acquire(sys.argv[1]);"
        "print('held', flush=True); sys.stdin.read()",
        str(out),
    )
    assert writer.stdout.readline() == "held\n", writer.stderr.read()
    assert main(["report", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"in use by pid {writer.pid}" in err and err.count("\n") == 1
    assert not (out / "report.md").exists()
    _release(writer)
    assert main(["report", str(out)]) == 0
    assert (out / "report.md").exists()


def test_wait_waits_until_the_holder_is_done(tmp_path, holder, spawn):
    out = tmp_path / "out"
    proc = holder(out)
    code = (
        "import sys; from idbench.cli.commands import main;"
        "sys.exit(main(['compare', *sys.argv[2:], '--out', sys.argv[1], '--wait',"
        " '-q']))"
    )
    waiter = spawn(code, str(out), *TINY)
    line = waiter.stderr.readline()  # said before it blocks
    assert "in use by" in line and f"pid {proc.pid}" in line and "waiting" in line
    assert waiter.poll() is None  # blocked: the holder still holds
    assert not (out / "runs.parquet").exists()
    _release(proc)
    assert waiter.wait() == 0, waiter.stderr.read()
    assert (out / "runs.parquet").exists()


def test_the_lock_goes_with_a_killed_holder(tmp_path, holder):
    out = tmp_path / "out"
    proc = holder(out)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    ResultStore(out, {"holder": 1}, {}).close()


def _forked_child(conn) -> None:
    conn.recv()  # alive, holding its copy of the parent's descriptors


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="no fork")
def test_a_forked_child_does_not_keep_the_lock(tmp_path):
    out = tmp_path / "out"
    acquire(out)
    parent, child = mp.Pipe()
    worker = mp.get_context("fork").Process(target=_forked_child, args=(child,))
    worker.start()
    try:
        release(out)  # the child lives on: the folder must be free anyway
        proc = _python(HOLDER, str(out))
        assert proc.stdout.readline() == "held\n", proc.stderr.read()
        _release(proc)
    finally:
        parent.send(None)
        worker.join()


def test_only_the_temporaries_of_gone_writers_are_removed(tmp_path, holder):
    out = tmp_path / "out"
    live = holder(tmp_path / "elsewhere")  # a live process writing something
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()  # reaped: its pid names no process
    ours = temporary_prefix(1).split("-")[2]
    other = "0" * 8 if ours != "0" * 8 else "1" * 8
    (out / "parts").mkdir(parents=True)
    names = {
        "live": f"{temporary_prefix(live.pid)}abcd.parquet",
        "gone": f"{temporary_prefix(done.pid)}abcd.parquet",
        "mine": f"{temporary_prefix(os.getpid())}abcd.parquet",
        "unnamed": ".tmp-leftover.parquet",  # an older idbench's
        "host": f".tmp-123-{other}-abcd.parquet",  # another host's
    }
    for folder in (out, out / "parts"):
        for name in names.values():
            (folder / name).write_bytes(b"half a file")
    ResultStore(out, {"holder": 1}, {}).close()
    for folder in (out, out / "parts"):
        left = {p.name for p in folder.glob(".tmp-*")}
        assert left == {names["live"], names["host"]}, folder
    _release(live)
