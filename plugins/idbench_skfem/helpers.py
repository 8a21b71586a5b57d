"""Helper processes that solve some of a batched step's pairs (option ``processes``).

With ``processes = n > 1`` a model's :func:`~idbench_skfem.batched.step_many`
hands the pairs its predictions do not settle to ``n - 1`` helper processes
and itself, in contiguous shares fixed by their order (so results do not
depend on timing). Each helper is a spawned process holding its own copy of
the model (rebuilt from the constructor's arguments) and its own
factorizations; a call ships predictions, residuals and thetas (a few vectors
of n floats) and gets the converged states and the work done back.

Threads do not pay here: a residual evaluation is some 40 numpy calls on
arrays of a few thousand elements, and two threads contending for the GIL run
them at half the speed of one (measured at 525 nodes); processes do not
share a GIL, and a pair (one factorization and a few chord iterations, ~4 ms at
525 nodes) is long against a round trip through a pipe (~0.1 ms).

A helper is ``python -m idbench_skfem.helpers`` on one end of a socket pair
(not a multiprocessing child: spawning one re-imports the caller's main
script, which a user's script without an ``if __name__ == "__main__"`` guard
cannot survive). It starts on first use (about a second to import and build
the model; the call waits for it, so the shares never depend on timing),
ignores SIGINT (the parent owns Ctrl-C) and ends when the parent closes its
end of the socket, or dies. If one
dies, its pairs are solved in the parent and it is not used again (a
warning says so); a :class:`~idbench.ModelFailure` in a helper is raised in
the parent as itself.
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
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
        self._process = subprocess.Popen(
            [sys.executable, "-m", __name__, str(theirs.fileno())],
            pass_fds=(theirs.fileno(),), env=env, stdin=subprocess.DEVNULL,
            start_new_session=True,  # Ctrl-C goes to the parent only
        )  # fmt: skip
        theirs.close()
        self._conn = Channel(ours)
        self._ready = False
        self._pending = False
        self.alive = True
        self.calls = 0
        """Calls answered (for tests and benchmarks)."""
        try:
            self._conn.send((build, solve))
        except OSError as exc:
            self._lost(exc)

    def submit(self, *args: Any) -> None:
        """Send one call; :meth:`collect` returns its result."""
        self._drain()
        try:
            self._wait_ready()
            self._conn.send(args)
        except (OSError, EOFError, HelperLost) as exc:
            self._lost(exc)
        self._pending = True

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
        self._pending = False
        if not self.alive:
            raise HelperLost("the helper process is gone")
        try:
            kind, value = self._conn.recv()
        except (OSError, EOFError) as exc:
            self._lost(exc)
            raise HelperLost("the helper process is gone") from exc
        if kind == "ok":
            self.calls += 1
            return value
        if kind == "failure":
            message, step = value
            raise ModelFailure(message) if step is None else _failure(message, step)
        self._lost(RuntimeError(value))
        raise HelperLost(value)

    def close(self) -> None:
        """Stop the process (idempotent)."""
        if self._process.poll() is None:
            try:
                self._conn.send(None)
            except (OSError, ValueError):
                pass
            try:
                self._process.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        self._conn.close()
        self.alive = False

    def _drain(self) -> None:
        """Discard an uncollected result (the caller raised before collecting)."""
        if self._pending and self.alive:
            self._pending = False
            try:
                self._conn.recv()
            except (OSError, EOFError) as exc:
                self._lost(exc)

    def _wait_ready(self) -> None:
        if self._ready:
            return
        if not self.alive:
            raise HelperLost("the helper process is gone")
        if not self._conn.poll(START_SECONDS):
            raise HelperLost(f"no answer within {START_SECONDS:.0f} s of starting")
        kind, value = self._conn.recv()
        if kind != "ready":
            raise HelperLost(str(value))
        self._ready = True

    def _lost(self, exc: BaseException) -> None:
        if self.alive:
            log.warning("a step helper process was lost (%s): solving in one", exc)
        self.alive = False
        if self._process.poll() is None:
            self._process.kill()
            self._process.wait()


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
    """The helper's loop: build the model, then answer calls until None or EOF."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        build, solve = conn.recv()
        model = build()
    except EOFError:
        return
    except Exception as exc:  # reported to the parent
        conn.send(("error", f"building the model failed: {exc!r}"))
        return
    conn.send(("ready", None))
    while True:
        try:
            args = conn.recv()
        except (EOFError, OSError):
            return
        if args is None:
            return
        try:
            conn.send(("ok", solve(model, *args)))
        except ModelFailure as exc:
            conn.send(("failure", (str(exc), exc.step)))
        except Exception as exc:  # reported to the parent
            conn.send(("error", f"{type(exc).__name__}: {exc}"))


if __name__ == "__main__":
    _serve(Channel(socket.socket(fileno=int(sys.argv[1]))))
