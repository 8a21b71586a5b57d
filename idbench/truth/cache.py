"""The disk cache: simulated states and calibrations, checked on load.

Plain arrays (``.npz``, never pickle) in one folder (:func:`cache_dir`), each
entry stored with its key: an entry that is missing, truncated, foreign or
altered is recomputed, not trusted. Writes are atomic (a temporary file
renamed into place); a folder that is not writable is warned about and the
work goes on uncached. The truth (:mod:`idbench.truth.simulate`) keeps its
states here, and a calibration (:mod:`idbench.calibrate`) its fine paths and
its fitted discrepancy.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs

from idbench.core.interfaces import FloatArray
from idbench.store.files import atomic_write, digest

log = logging.getLogger(__name__)

CACHE_ENV = "IDBENCH_CACHE_DIR"
"""The environment variable that names the cache folder."""


def cache_dir() -> Path:
    """The truth cache folder: ``$IDBENCH_CACHE_DIR`` or the user cache dir."""
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else Path(platformdirs.user_cache_dir("idbench"))


def read_entry(
    path: Path, key: str, check: Callable[[dict[str, Any]], None], what: str
) -> dict[str, Any] | None:
    """The arrays of the cache entry at ``path``, or None if missing or untrusted.

    The entry must hold ``key``; ``check(arrays)`` raises ``ValueError`` for
    content not to be trusted (shape, digest). An unusable entry is logged
    (``what``: ``"truth"``, ``"discrepancy"``) and None returned: recomputed.
    """
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                raise ValueError("key mismatch")
            arrays = {name: np.array(data[name]) for name in data.files}
        check(arrays)
        return arrays
    except Exception as exc:  # truncated, foreign or altered file: recompute
        log.warning("%s cache entry %s unusable (%s); recomputing", what, path, exc)
        return None


def write_entry(path: Path, key: str, arrays: dict[str, Any], what: str) -> None:
    """Store ``arrays`` with ``key`` atomically (``.npz``, no pickle), or warn."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, key=np.array(key), **arrays)

    try:
        atomic_write(path, write)
    except OSError as exc:
        log.warning(
            "%s cache %s is not writable (%s); going on without caching",
            what,
            path.parent,
            exc,
        )


def read_states(path: Path, key: str, shape: tuple[int, int]) -> FloatArray | None:
    """The cached states at ``path``, or None if missing or not to be trusted.

    An entry is trusted only if its key, its shape and the SHA-256 digest of its
    content (stored with it) all match: a truncated, foreign or altered file is
    recomputed.
    """

    def check(arrays: dict[str, Any]) -> None:
        states = arrays["states"]
        if states.shape != shape:
            raise ValueError(f"states of shape {states.shape}, expected {shape}")
        stored = str(arrays["digest"]) if "digest" in arrays else ""
        if not stored:
            raise ValueError("written by an older idbench (no content digest)")
        if stored != digest(np.asarray(states, dtype=float)):
            raise ValueError("content digest mismatch (altered or damaged)")
        if not np.all(np.isfinite(states)):
            raise ValueError("non-finite states")

    arrays = read_entry(path, key, check, "truth")
    return None if arrays is None else np.array(arrays["states"], dtype=float)


def write_states(path: Path, key: str, states: FloatArray) -> None:
    """Store ``states`` with its key and digest; warn (not fail) if impossible."""
    write_entry(path, key, {"states": states, "digest": digest(states)}, "truth")
