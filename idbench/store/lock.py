"""One writer per folder: an operating-system lock on ``DIR/.lock``.

An output folder is written by one process at a time. :func:`acquire` takes
an exclusive lock on the file ``DIR/.lock`` (``fcntl.flock`` on Linux and
macOS, ``msvcrt.locking`` on Windows) and records in it who holds it: the
process id, the host, since when and the command. A second process is refused
with one line naming that holder, or waits for it (``wait=True``). The
operating system releases the lock when the holder exits, however it ends
(also ``kill -9``), so a lock is never left behind; the file itself stays (it
is never deleted: another process may be waiting on it).

Within a process the lock is re-entrant (a count per folder): a command that
holds it across a sweep and its report opens the results store inside. A
forked child does not inherit the hold: it closes its copy of the descriptor
(without unlocking, which would release the parent's lock too).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shlex
import socket
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

LOCK_NAME = ".lock"
"""The lock file's name inside the folder."""

_WINDOWS_OFFSET = 1 << 30
"""Byte locked on Windows: past the holder's note, so others can read it."""


class FolderBusy(RuntimeError):
    """Another process holds the folder's lock."""


@dataclass
class _Hold:
    fd: int
    count: int


_held: dict[str, _Hold] = {}
_guard = threading.Lock()


def _key(folder: Path) -> str:
    return os.path.realpath(folder)


def holder(folder: str | Path) -> str:
    """Who holds ``folder``'s lock, as recorded in its lock file (one phrase)."""
    try:
        note = json.loads((Path(folder) / LOCK_NAME).read_text())
        return (
            f"pid {note['pid']} on host {note['host']} since {note['since']} "
            f"({note['command']})"
        )
    except (OSError, ValueError, KeyError, TypeError):
        return "another process (it has not recorded itself yet)"


def acquire(folder: str | Path, *, wait: bool = False, hint: str = "") -> None:
    """Take the lock of ``folder`` (created if missing) for this process.

    Parameters
    ----------
    folder
        The folder to lock.
    wait
        If another process holds it, wait until it is released (logging who
        holds it once) instead of raising.
    hint
        Appended to the refusal, e.g. what to do instead.

    Raises
    ------
    FolderBusy
        Another process holds the lock and ``wait`` is false; one line naming
        the holder.
    OSError
        The folder or its lock file cannot be created.
    """
    folder = Path(folder)
    key = _key(folder)
    with _guard:
        if key in _held:
            _held[key].count += 1
            return
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        if not _try_lock(fd):
            if not wait:
                raise FolderBusy(f"{folder} is in use by {holder(folder)}{hint}")
            log.warning("%s is in use by %s; waiting for it", folder, holder(folder))
            _lock(fd)
        _record(fd)
    except BaseException:
        os.close(fd)  # closing the only descriptor releases a lock it took
        raise
    with _guard:
        _held[key] = _Hold(fd, 1)


def release(folder: str | Path) -> None:
    """Give back one hold of ``folder``'s lock; the last one unlocks it."""
    key = _key(Path(folder))
    with _guard:
        hold = _held.get(key)
        if hold is None:
            return
        hold.count -= 1
        if hold.count:
            return
        del _held[key]
    with contextlib.suppress(OSError):
        os.ftruncate(hold.fd, 0)  # the note would name a process that left
    os.close(hold.fd)


@contextlib.contextmanager
def hold(folder: str | Path, *, wait: bool = False, hint: str = "") -> Iterator[None]:
    """:func:`acquire` ``folder`` for the ``with`` block, then :func:`release`."""
    acquire(folder, wait=wait, hint=hint)
    try:
        yield
    finally:
        release(folder)


def _record(fd: int) -> None:
    note = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "since": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "command": shlex.join([Path(sys.argv[0]).name, *sys.argv[1:]])[:300],
    }
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, json.dumps(note).encode())


if sys.platform == "win32":  # pragma: no cover - not tested here
    import msvcrt

    def _try_lock(fd: int) -> bool:
        os.lseek(fd, _WINDOWS_OFFSET, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True

    def _lock(fd: int) -> None:
        while not _try_lock(fd):
            time.sleep(0.5)

else:
    import fcntl

    def _try_lock(fd: int) -> bool:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        except OSError as exc:  # e.g. ENOLCK: a network file system without locks
            log.warning("cannot lock (%s): going on without a lock", exc)
        return True

    def _lock(fd: int) -> None:
        fcntl.flock(fd, fcntl.LOCK_EX)


def _forget_in_child() -> None:
    """In a forked child: close the inherited descriptors, keep the parent's lock."""
    global _guard
    _guard = threading.Lock()  # another thread may have held it at the fork
    for hold_ in _held.values():
        with contextlib.suppress(OSError):
            os.close(hold_.fd)
    _held.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_child)
