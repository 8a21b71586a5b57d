"""Helper processes that solve some of a batched step's pairs (option ``processes``).

With ``processes = n > 1`` a model's
:meth:`~idbench_fem.fem.batched.BatchedSteps.step_many`
splits the pairs it must iterate between ``n - 1`` helper processes and
itself, in contiguous shares fixed by their order (so results do not depend
on timing; see :mod:`idbench_fem.fem.batched` for which pairs and when). Each
helper is a process holding its own copy of the model (rebuilt from the
constructor's arguments) and its own factorizations; a call ships thetas,
predictions and given states (a few vectors of n floats) and gets the
converged states and the work done back. One model's helpers run at a time
in a process (:func:`start`).

Threads did not pay here: a numpy residual evaluation is some 40 numpy calls
on arrays of a few thousand elements, and two threads contending for the GIL
ran them at half the speed of one (measured at 525 nodes, before the compiled
kernel of :mod:`idbench_fem.fem.kernels`, which releases the GIL); processes do not
share a GIL, and a pair (one factorization and a few chord iterations, ~4 ms at
525 nodes) is long against a round trip through a pipe (~0.1 ms).

A helper is a Python process running :func:`serve` on one end of a socket
pair (``python -c`` importing this module: not ``-m``, which would run a
second copy of it beside the one the package imports; and not a
multiprocessing child: spawning one re-imports the caller's main
script, which a user's script without an ``if __name__ == "__main__"`` guard
cannot survive). It starts on first use (about a second to import and build
the model; the call waits for it, so the shares never depend on timing),
ignores SIGINT (the parent owns Ctrl-C), runs one BLAS thread, and ends
quietly when the parent closes its end of the socket, or dies (also in the
middle of a solve: a thread checks the parent every half second). If a helper
dies or a message to or from it is cut short (also by a Ctrl-C while the
parent waits), its pairs are solved in the parent and it is not used again
(a warning says so); a :class:`~idbench.ModelFailure` in a helper is raised
in the parent as itself.
"""

from __future__ import annotations

import logging
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import weakref
from collections.abc import Callable
from multiprocessing.reduction import ForkingPickler
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench import ModelFailure

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

START_SECONDS = 120.0
"""How long a helper may take to import and build its model."""

WATCH_SECONDS = 0.5
"""How often a helper checks that its parent is alive."""

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
"""Set to 1 in a helper's environment unless set already: a helper is one core."""


HELPER_MAIN = f"import sys; from {__name__} import serve; serve(int(sys.argv[1]))"
"""What a helper process runs (``python -c``), given its socket's descriptor."""


class HelperLost(RuntimeError):
    """A helper process died or answered nonsense; its pairs run in the parent."""


class Helper:
    """One helper process serving ``solve(model, *args)`` calls on its own model.

    Parameters
    ----------
    build
        A picklable callable returning the model (run in the helper).
    solve
        A picklable callable ``solve(model, *args) -> (result, work)`` run in
        the helper for each :meth:`submit`.
    """

    def __init__(self, build: Callable[[], Any], solve: Callable[..., Any]) -> None:
        ours, theirs = socket.socketpair()
        self._conn = Channel(ours)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
        for name in THREAD_VARIABLES:  # one core's worth of work
            env.setdefault(name, "1")
        try:
            self._process = subprocess.Popen(
                [sys.executable, "-c", HELPER_MAIN, str(theirs.fileno())],
                pass_fds=(theirs.fileno(),), env=env, stdin=subprocess.DEVNULL,
                start_new_session=True,  # Ctrl-C goes to the parent only
            )  # fmt: skip
        except BaseException:
            self._conn.close()
            raise
        finally:
            theirs.close()
        self._pid = os.getpid()
        self._ready = False
        self._pending = False
        self.alive = True
        self.closed = False
        """Whether :meth:`close` stopped it (not lost: it may be started again)."""
        self.calls = 0
        """Calls answered (for tests and benchmarks)."""
        self._io(self._conn.send, (build, solve))

    @property
    def owned(self) -> bool:
        """Whether this process started it (not a forked copy of its starter).

        A process forked from the starter (a sweep's forked worker) holds a
        copy of the socket: it must neither talk to the helper nor stop it.
        """
        return os.getpid() == self._pid

    def submit(self, *args: Any) -> None:
        """Send one call; :meth:`collect` returns its result."""
        if self._pending:  # the caller raised before collecting the last one
            self._pending = False
            self._io(self._conn.recv)
        if not self._ready and self.alive:
            if not self._io(self._conn.poll, START_SECONDS):
                self._lost(f"no answer within {START_SECONDS:.0f} s of starting")
            else:
                kind, value = self._io(self._conn.recv) or (None, None)
                if kind == "ready":
                    self._ready = True
                elif self.alive:
                    self._lost(str(value))
        self._pending = True  # before sending: an answer is never left unclaimed
        self._io(self._conn.send, args)

    def collect(self) -> Any:
        """The result of the last :meth:`submit`.

        Raises
        ------
        ModelFailure
            Raised in the helper by the model.
        HelperLost
            The helper died (or was lost before); the caller does the work.
        """
        if not self._pending:
            raise RuntimeError("collect() without submit()")
        self._pending = False  # before reading: an answer is never read twice
        answer = self._io(self._conn.recv)
        if not self.alive:
            raise HelperLost("the helper process is gone")
        kind, value = answer
        if kind == "ok":
            self.calls += 1
            return value
        if kind == "failure":
            message, step = value
            raise ModelFailure(message) if step is None else _failure(message, step)
        self._lost(str(value))
        raise HelperLost(value)

    def close(self) -> None:
        """Stop the process and close the socket (idempotent).

        In a forked copy (not :attr:`owned`) only the copy of the socket is
        closed: the helper goes on serving the process that started it.
        """
        if not self.owned:
            self._conn.close()
            self.alive, self.closed = False, True
            if self._process.returncode is None:  # not our child: never reaped here
                self._process.returncode = 0
            return
        if self._process.poll() is None:
            if self.alive:
                self._io(self._conn.send, None)
            try:
                self._process.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        self._conn.close()
        self.alive = False
        self.closed = True

    def _io(self, op: Callable[..., Any], *args: Any) -> Any:
        """``op(*args)`` on the socket; the helper is lost if it does not complete.

        Any exception (a dead helper, a garbled message, or a KeyboardInterrupt
        half way through a message, which would leave the stream out of step)
        loses the helper, so its pairs run here from then on; a
        KeyboardInterrupt is raised again.
        """
        if not self.alive:
            return None
        try:
            return op(*args)
        except BaseException as exc:
            self._lost(f"{type(exc).__name__}: {exc}")
            if not isinstance(exc, Exception):
                raise
            return None

    def _lost(self, why: str) -> None:
        if not self.owned:  # not ours to stop (see close)
            self.close()
            return
        if self.alive:
            log.warning("a step helper process was lost (%s): solving here", why)
        self.alive = False
        if self._process.poll() is None:
            self._process.kill()
            self._process.wait()
        self._conn.close()


_RUNNING = threading.local()
"""Per thread (sessions and their models are per thread): ``owner``, a weak
reference to the model whose helpers run, and ``helpers``."""


def start(
    owner: Any, count: int, build: Callable[[], Any], solve: Callable[..., Any]
) -> list[Helper]:
    """Start ``count`` helpers for ``owner``, stopping those of any other owner.

    One owner's helpers run at a time in a thread, so a sweep that caches
    many models keeps ``count`` helpers a thread, not ``count`` a model; an
    owner whose helpers were stopped starts them again when it needs them.
    Returns [] (with a warning) if a process cannot be started.
    """
    running = getattr(_RUNNING, "owner", None)
    if running is not None and running() is not owner:
        close_all(_RUNNING.helpers)
    helpers: list[Helper] = []
    try:
        for _ in range(count):
            helpers.append(Helper(build, solve))
    except Exception as exc:  # reported, and the model solves alone
        log.warning("cannot start a step helper process (%s): solving here", exc)
        close_all(helpers)
        helpers = []
    _RUNNING.owner, _RUNNING.helpers = weakref.ref(owner), helpers
    return helpers


def close_all(helpers: list[Helper]) -> None:
    """Close every helper of ``helpers``."""
    for helper in helpers:
        helper.close()


class Channel:
    """Messages over a stream socket, each after its length (8 bytes).

    Messages are serialised as multiprocessing's own connections do
    (:class:`multiprocessing.reduction.ForkingPickler`), between this process
    and the helper it started, over a private socket pair; nothing is read from
    disk or from anyone else.

    Writes never raise SIGPIPE (MSG_NOSIGNAL, or SO_NOSIGPIPE on macOS): Python
    ignores the signal, but a library may restore its default (gmsh does), and
    a write to a helper that just died would then kill this process; here it
    raises OSError instead, and the helper counts as lost.
    """

    _FLAGS = getattr(socket, "MSG_NOSIGNAL", 0)

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock
        if hasattr(socket, "SO_NOSIGPIPE"):  # pragma: no cover (macOS)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_NOSIGPIPE, 1)

    def send(self, message: Any) -> None:
        """Send one message (OSError if the other end is gone)."""
        data = bytes(ForkingPickler.dumps(message))
        self._sock.sendall(struct.pack("!Q", len(data)) + data, self._FLAGS)

    def recv(self) -> Any:
        """The next message (EOFError if the other end closed)."""
        (size,) = struct.unpack("!Q", self._read(8))
        return ForkingPickler.loads(self._read(size))

    def poll(self, timeout: float) -> bool:
        """Whether a message (or EOF) is ready within ``timeout`` seconds."""
        return bool(select.select([self._sock], [], [], timeout)[0])

    def close(self) -> None:
        """Close this end (the other end then reads EOF)."""
        self._sock.close()

    def _read(self, size: int) -> bytes:
        buf = bytearray(size)
        view, got = memoryview(buf), 0
        while got < size:
            n = self._sock.recv_into(view[got:], size - got)
            if n == 0:
                raise EOFError("the other end closed")
            got += n
        return bytes(buf)


def _failure(message: str, step: int) -> ModelFailure:
    """A ModelFailure with ``message`` as its full text and ``step`` set."""
    exc = ModelFailure(message)
    exc.step = step
    return exc


def _serve(conn: Channel) -> None:
    """The helper's loop: build the model, then answer calls until None or EOF.

    Ends quietly when the parent is gone (EOF, or a failed write).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        try:
            build, solve = conn.recv()
            model = build()
        except (EOFError, OSError):
            raise
        except Exception as exc:  # reported to the parent
            conn.send(("error", f"building the model failed: {exc!r}"))
            return
        conn.send(("ready", None))
        while (args := conn.recv()) is not None:
            try:
                answer = ("ok", solve(model, *args))
            except ModelFailure as exc:
                answer = ("failure", (str(exc), exc.step))
            except Exception as exc:  # reported to the parent
                answer = ("error", f"{type(exc).__name__}: {exc}")
            conn.send(answer)
    except (EOFError, OSError):
        return


def _watch(parent: int) -> None:
    """End this process at once when its parent is gone.

    A helper inside a long solve reads nothing, so without this it would
    outlive a killed parent until its next message; the check costs one
    ``getppid`` every :data:`WATCH_SECONDS`.
    """
    while os.getppid() == parent:
        time.sleep(WATCH_SECONDS)
    os._exit(0)


def serve(fd: int) -> None:
    """A helper process's main: answer calls on the socket ``fd`` (see the module).

    Ends the process when its parent is gone.
    """
    threading.Thread(target=_watch, args=(os.getppid(),), daemon=True).start()
    _serve(Channel(socket.socket(fileno=fd)))
