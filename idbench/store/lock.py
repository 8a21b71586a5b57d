"""One writer per folder: an operating-system lock on ``DIR/.lock``.

An output folder is written by one process at a time. :func:`acquire` takes
an exclusive lock on the file ``DIR/.lock`` (``fcntl.flock`` on Linux and
macOS, ``msvcrt.locking`` on Windows) and records in it who holds it: the
process id, the host, since when and the command. A second process is refused
with one line naming that holder, or waits for it (``wait=True``). The
operating system releases the lock when the holder exits, however it ends
(also ``kill -9``), so a lock is never left behind; the file itself stays,
except where a start failed in a folder that the failed start created
(:func:`abandon`): a waiter that then holds a deleted file's lock sees it and
opens the new one. The lock file is never a symbolic link: it is opened without
following one (a link to another file would be truncated by the holder's note).

Within a process the lock is re-entrant (a count per folder): a command that
holds it across a sweep and its report opens the results store inside. A
forked child does not inherit the hold: it closes its copy of the descriptor
(without unlocking, which would release the parent's lock too).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import shlex
import socket
import stat
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
    created: Path | None = None  # the topmost folder this hold created
    abandon: bool = False  # remove what it created when the last hold goes


_held: dict[str, _Hold] = {}
_guard = threading.Lock()


def _key(folder: Path) -> str:
    return os.path.realpath(folder)


def holder(folder: str | Path) -> str:
    """Who holds ``folder``'s lock, as recorded in its lock file (one phrase)."""
    path = Path(folder) / LOCK_NAME
    try:
        if path.is_symlink():
            return "another process (its lock file is a symbolic link)"
        note = json.loads(path.read_text())
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
    path = folder / LOCK_NAME
    while True:
        created = _topmost_missing(folder)
        folder.mkdir(parents=True, exist_ok=True)
        try:
            fd = _open(path)
        except FileNotFoundError:  # another process abandoned the folder meanwhile
            continue
        try:
            if not _try_lock(fd):
                if not wait:
                    raise FolderBusy(f"{folder} is in use by {holder(folder)}{hint}")
                log.warning("%s is in use by %s; waiting", folder, holder(folder))
                _lock(fd)
            if _still_there(fd, path):
                _record(fd)
                break
        except BaseException:
            os.close(fd)  # closing the only descriptor releases a lock it took
            raise
        os.close(fd)  # its folder was abandoned while we waited: lock the new one
    with _guard:
        _held[key] = _Hold(fd, 1, created)


def _topmost_missing(folder: Path) -> Path | None:
    """The topmost folder of ``folder``'s path that does not exist yet, if any."""
    missing = None
    for candidate in (folder, *folder.parents):
        if candidate.exists():
            break
        missing = candidate
    return missing


def _open(path: Path) -> int:
    """The lock file's descriptor, never through a symbolic link.

    Raises
    ------
    OSError
        ``path`` is a symbolic link or not a regular file (naming it).
    """
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
    if os.path.islink(path):
        raise OSError(
            errno.ELOOP, "is a symbolic link; idbench never follows one (remove it)",
            str(path),
        )
    if os.path.lexists(path) and not stat.S_ISREG(os.lstat(path).st_mode):
        raise OSError(errno.EINVAL, "is not a regular file (remove it)", str(path))
    fd = os.open(path, flags, 0o666)
    if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced meanwhile
        os.close(fd)
        raise OSError(errno.EINVAL, "is not a regular file (remove it)", str(path))
    return fd


def _still_there(fd: int, path: Path) -> bool:
    """Whether ``fd`` is still the file at ``path`` (not one abandoned meanwhile)."""
    try:
        now = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    mine = os.fstat(fd)
    return (mine.st_dev, mine.st_ino) == (now.st_dev, now.st_ino)


def abandon(folder: str | Path) -> None:
    """Give back one hold after a failed start, and leave nothing behind.

    When the last hold of this process is given back, if it created the
    folder and nothing but the lock file is in it, the lock file and the
    folders the hold created are removed (a waiter then sees its lock file
    gone and opens a new one); else it is :func:`release`.
    """
    with _guard:
        hold = _held.get(_key(Path(folder)))
        if hold is not None:
            hold.abandon = True
    release(folder)


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
    folder = Path(folder)
    if hold.abandon and hold.created is not None and _only_the_lock(folder):
        with contextlib.suppress(OSError):
            (folder / LOCK_NAME).unlink()  # before the unlock: waiters see it gone
        os.close(hold.fd)
        for empty in (folder, *folder.parents):
            with contextlib.suppress(OSError):
                empty.rmdir()
            if empty == hold.created:
                break
        return
    with contextlib.suppress(OSError):
        os.ftruncate(hold.fd, 0)  # the note would name a process that left
    os.close(hold.fd)


def _only_the_lock(folder: Path) -> bool:
    """Whether ``folder`` holds nothing but its lock file."""
    try:
        return {p.name for p in folder.iterdir()} <= {LOCK_NAME}
    except OSError:
        return False


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
