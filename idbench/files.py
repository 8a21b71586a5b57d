"""Stable hashes and atomic file writes, shared by the cache and the results.

Every file idbench writes goes through a temporary file in the same folder and
a rename, so a reader (or a kill) never sees half a file; the file then gets
the permissions the process's umask gives ordinary files (``mkstemp`` alone
would leave it readable by its owner only, which breaks a cache shared by a
cluster's group).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

TMP_PREFIX = ".tmp-"
"""Prefix of the temporary files; leftovers of a killed process start with it."""


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
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=TMP_PREFIX, suffix=path.suffix)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


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
    """Delete temporary files a killed process left in ``folder``; count them."""
    count = 0
    for tmp in Path(folder).glob(f"{TMP_PREFIX}*"):
        try:
            tmp.unlink()
            count += 1
        except OSError:
            pass
    return count
