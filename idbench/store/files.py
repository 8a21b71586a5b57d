"""Stable hashes and atomic file writes, shared by the cache and the results.

Every file idbench writes goes through a temporary file in the same folder and
a rename, so a reader (or a kill) never sees half a file; the file then gets
the permissions the process's umask gives ordinary files (``mkstemp`` alone
would leave it readable by its owner only, which breaks a cache shared by a
cluster's group). A temporary file is named after its owner
(``.tmp-PID-HOST-...``, HOST a hash of the host name), so that a cleaner
removes only those of processes that are gone (:func:`remove_stale_temporaries`),
never another live writer's. A failed write names the file it was writing
(a full disk's ``OSError`` alone does not).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import socket
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

TMP_PREFIX = ".tmp-"
"""Prefix of the temporary files; leftovers of a killed process start with it."""

_HOST = hashlib.sha256(socket.gethostname().encode()).hexdigest()[:8]
_OWNED = re.compile(re.escape(TMP_PREFIX) + r"(\d+)-([0-9a-f]{8})-")


def temporary_prefix(pid: int | None = None) -> str:
    """Name prefix of the temporary files of process ``pid`` (default: this one)."""
    return f"{TMP_PREFIX}{os.getpid() if pid is None else pid}-{_HOST}-"


def stable_hash(obj: Any, length: int = 16) -> str:
    """Hex digest of the canonical JSON form of ``obj``."""
    text = json.dumps(obj, sort_keys=True, default=_jsonable, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def digest(array: Any) -> str:
    """SHA-256 of an array's dtype, shape and bytes (C order)."""
    a = np.ascontiguousarray(array)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple | set | frozenset):
        return list(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    """Create ``path`` by ``write(tmp)`` on a temporary sibling, then rename.

    Parameters
    ----------
    path
        The file to create or replace; its folder is created if missing.
    write
        Writes the content to the temporary path it is given.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, name = tempfile.mkstemp(
            dir=path.parent, prefix=temporary_prefix(), suffix=path.suffix
        )
    except OSError as exc:
        raise _naming(exc, path) from None
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _naming(exc, path) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


_HINTS = {
    errno.ENOSPC: " (the disk is full: free space, or write elsewhere)",
    errno.EDQUOT: " (the disk quota is exceeded: free space, or write elsewhere)",
    errno.EACCES: " (no permission to write there: write elsewhere)",
    errno.EPERM: " (no permission to write there: write elsewhere)",
    errno.EROFS: " (a read-only file system: write elsewhere)",
}
"""What to do about the write errors a user can fix, by errno."""


def _naming(exc: OSError, path: Path) -> OSError:
    """``exc`` naming ``path`` (the file being written), not its temporary."""
    if exc.errno is None:  # e.g. pyarrow's: its text, then the path
        return OSError(f"{' '.join(str(exc).split())} writing {str(path)!r}")
    text = exc.strerror or os.strerror(exc.errno)
    text += _HINTS.get(exc.errno, "")
    return type(exc)(exc.errno, f"{text} writing", str(path))


def describe(exc: OSError) -> str:
    """An ``OSError`` as one phrase: the file, then the cause (``[Errno N]`` left out).

    Example: ``'/out/manifest.json': No space left on device (the disk is
    full: ...)``.
    """
    if exc.errno is None or exc.strerror is None:
        return " ".join(str(exc).split())
    cause = exc.strerror
    if exc.errno in _HINTS and _HINTS[exc.errno] not in cause:
        cause += _HINTS[exc.errno]
    return f"{exc.filename!r}: {cause}" if exc.filename else cause


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (flushed to disk before the rename)."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())

    atomic_write(path, write)


def atomic_write_parquet(df: Any, path: Path) -> None:
    """Write the pandas DataFrame ``df`` as parquet to ``path`` atomically."""
    atomic_write(path, lambda tmp: df.to_parquet(tmp, index=False))


def remove_stale_temporaries(folder: Path) -> int:
    """Delete temporary files a killed process left in ``folder``; count them.

    Removed: this process's own, those of a process of this host that is gone,
    and unnamed ones (left by an idbench that named no owner). Kept: those of a
    live process, and those of another host (whose processes cannot be
    checked from here).
    """
    count = 0
    for tmp in Path(folder).glob(f"{TMP_PREFIX}*"):
        if not tmp.is_file() or _owner_alive(tmp.name):
            continue
        try:
            tmp.unlink()
            count += 1
        except OSError:
            pass
    return count


def _owner_alive(name: str) -> bool:
    """Whether the process that writes the temporary file ``name`` may be running."""
    m = _OWNED.match(name)
    if m is None:
        return False  # no owner recorded: an older idbench's leftover
    pid, host = int(m.group(1)), m.group(2)
    if host != _HOST:
        return True
    if pid == os.getpid():
        return False
    if sys.platform == "win32":  # os.kill would end the process there
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process: it exists
        return True
    return True
