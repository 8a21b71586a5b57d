"""The fine-mesh truth: simulate a load path once, cache it on disk.

The cache holds plain arrays (``.npz``, never pickle), keyed by a hash of the
model's own description, the true parameters and the idbench version. Probe
settings (markers, grid) do not change the states, so they are left out of the
key: the states are cached and probed again on load. Writes are atomic (a
temporary file renamed into place) and an unreadable entry is recomputed.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs

from idbench.interfaces import FloatArray, ForwardModel

log = logging.getLogger(__name__)

CACHE_ENV = "IDBENCH_CACHE_DIR"
PROBE_KEYS = ("probes", "markers", "grid", "marker_points", "grid_points")


def cache_dir() -> Path:
    """The truth cache folder: ``$IDBENCH_CACHE_DIR`` or the user cache dir."""
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else Path(platformdirs.user_cache_dir("idbench"))


@dataclass(frozen=True)
class Truth:
    """A simulated load path, probed.

    Attributes
    ----------
    states
        Free displacements per step, shape (K, n).
    observations
        Noise-free marker displacements per step, shape (K, m).
    grid
        Shape-error grid displacements per step, shape (K, G, 3).
    tip
        Tip displacement per step, shape (K, 3) (NaN if the model has no tip).
    """

    states: FloatArray
    observations: FloatArray
    grid: FloatArray
    tip: FloatArray


def stable_hash(obj: Any, length: int = 16) -> str:
    """Hex digest of the canonical JSON form of ``obj``."""
    text = json.dumps(obj, sort_keys=True, default=_jsonable, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (tuple, set, frozenset)):
        return list(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def truth_key(model: ForwardModel, theta: FloatArray) -> str:
    """Cache key for the truth of ``model`` at ``theta``."""
    from idbench import __version__

    desc = {k: v for k, v in model.describe().items() if k not in PROBE_KEYS}
    return stable_hash(
        {
            "model": desc,
            "theta": [float(t) for t in np.atleast_1d(theta)],
            "version": __version__,
        },
        length=24,
    )


def simulate_path(
    model: ForwardModel,
    theta: FloatArray,
    n_steps: int | None = None,
    on_step: Callable[[int, int], None] | None = None,
) -> FloatArray:
    """States (K, n) of the whole load path at fixed ``theta``.

    ``on_step(k, K)``, if given, is called after each step (for progress).
    """
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    n_steps = model.n_steps if n_steps is None else n_steps
    state = model.reset()
    states = np.empty((n_steps, state.size))
    for k in range(1, n_steps + 1):
        state = model.step(theta, k, state)
        states[k - 1] = state
        if on_step is not None:
            on_step(k, n_steps)
    return states


def probe(model: ForwardModel, states: FloatArray) -> Truth:
    """Observations, grid and tip displacements of each state."""
    tip = getattr(model, "tip", None)
    return Truth(
        states=states,
        observations=np.array([model.observe(s) for s in states]),
        grid=np.array([model.grid(s) for s in states]),
        tip=np.array([tip(s) if tip else np.full(3, np.nan) for s in states]),
    )


def simulate_truth(
    model: ForwardModel, theta: FloatArray, *, cache: bool = True
) -> Truth:
    """Simulate ``model`` at ``theta`` over its path, through the disk cache.

    Parameters
    ----------
    model
        The truth model (fine mesh).
    theta
        True parameters, shape (p,).
    cache
        Read and write the cache; ``False`` always simulates.
    """
    key = truth_key(model, theta)
    path = cache_dir() / f"truth-{key}.npz"
    states = _load(path, key) if cache else None
    if states is None:
        log.info("simulating truth %s", key)
        desc = model.describe()
        parts = [desc.get("mesh"), desc.get("scenario")]
        what = " ".join(
            str(v.get("name", "") if isinstance(v, dict) else v) for v in parts if v
        )
        t0 = time.perf_counter()

        def on_step(k: int, n: int) -> None:
            log.info(
                "truth %s: step %d/%d, %.0f s",
                what or key, k, n, time.perf_counter() - t0,
            )  # fmt: skip

        states = simulate_path(model, theta, on_step=on_step)
        if cache:
            _save(path, key, states)
    return probe(model, states)


def _load(path: Path, key: str) -> FloatArray | None:
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                raise ValueError("key mismatch")
            states = np.array(data["states"], dtype=float)
        if not np.all(np.isfinite(states)):
            raise ValueError("non-finite states")
        return states
    except Exception as exc:  # truncated or foreign file: recompute
        log.warning("truth cache entry %s unreadable (%s); recomputing", path, exc)
        return None


def _save(path: Path, key: str, states: FloatArray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, key=np.array(key), states=states)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
