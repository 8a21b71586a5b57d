"""The fine-mesh truth: simulate a load path once, cache it on disk.

The cache holds plain arrays (``.npz``, never pickle), keyed by a hash of the
model's own description, the true parameters and the idbench version. Probe
settings (markers, grid) do not change the states, so they are left out of the
key: the states are cached and probed again on load. Writes are atomic (a
temporary file renamed into place) and an unreadable entry is recomputed.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs

from idbench.core.capabilities import member, n_nodes_of, probes_of
from idbench.core.interfaces import FloatArray, ForwardModel, ModelFailure
from idbench.store.files import atomic_write, digest, stable_hash

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
        Shape-error point displacements per step, shape (K, G, d).
    probes
        The model's named outputs per step, name -> (K,) (empty if the model
        has no ``probes``).
    nodes
        The truth model's ``n_nodes`` (NaN if it does not say).
    targets
        Hidden-target displacements per step, shape (K, T, 3), or None if the
        model has no ``targets`` (:class:`~idbench.core.interfaces.TargetModel`)
        or none to show (T = 0).
    held_points
        A recording's held-out points per step (K, N, 3), NaN rows where a
        frame has fewer, scored by their distance to the model's surface; None
        without (every simulated truth).
    """

    states: FloatArray
    observations: FloatArray
    grid: FloatArray
    probes: dict[str, FloatArray]
    nodes: float = float("nan")
    targets: FloatArray | None = None
    held_points: FloatArray | None = None


def truth_key(model: ForwardModel, theta: FloatArray) -> str:
    """Cache key for the truth of ``model`` at ``theta``."""
    from idbench.core.version import __version__

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
    """Observations, shape-error points and probes of each state."""
    probes = probes_of(model)
    targets = member(model, "targets")
    named: dict[str, list[float]] = {}
    if probes is not None:
        for s in states:
            for name, value in probes(s).items():
                named.setdefault(name, []).append(float(value))
    nodes = n_nodes_of(model)
    return Truth(
        states=states,
        observations=np.array([model.observe(s) for s in states]),
        grid=np.array([model.grid(s) for s in states]),
        probes={name: np.array(values) for name, values in named.items()},
        nodes=float("nan") if nodes is None else float(nodes),
        targets=_targets(targets, states),
    )


def _targets(targets: Any, states: FloatArray) -> FloatArray | None:
    """Target displacements (K, T, 3) of the states; None without targets."""
    if not callable(targets) or not len(states):
        return None
    moved = np.array([targets(s) for s in states], dtype=float)
    return moved if moved.size else None


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
    shape = (model.n_steps, model.reset().size)
    states = _load(path, key, shape) if cache else None
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
        _check_finite(states, "states")
        if cache:
            _save(path, key, states)
    truth = probe(model, states)
    for what in ("observations", "grid"):
        _check_finite(getattr(truth, what), f"{what} (probed from its states)")
    return truth


def _check_finite(values: FloatArray, what: str) -> None:
    """Raise ModelFailure at the first step whose ``values`` are not finite.

    A truth that is not finite would fail every estimator run, blamed on it.
    """
    bad = ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad)) + 1
        raise ModelFailure(
            f"the truth model returned non-finite {what} ({int(bad.sum())} of "
            f"{len(values)} steps)",
            step=k,
        )


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


def _load(path: Path, key: str, shape: tuple[int, int]) -> FloatArray | None:
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


def _save(path: Path, key: str, states: FloatArray) -> None:
    """Store ``states`` with its key and digest; warn (not fail) if impossible."""
    write_entry(path, key, {"states": states, "digest": digest(states)}, "truth")
