"""The fine-mesh truth: simulate a load path once, cache it on disk.

The states are cached (:mod:`idbench.truth.cache`), keyed by a hash of the
model's own description, the true parameters and the idbench version. Probe
settings (markers, grid) do not change the states, so they are left out of the
key: the states are cached and probed again on load.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from idbench.core.capabilities import (
    load_figures_of,
    member,
    n_nodes_of,
    probes_of,
)
from idbench.core.interfaces import (
    FloatArray,
    ForwardModel,
    ModelError,
    ModelFailure,
)
from idbench.store.files import stable_hash
from idbench.truth.cache import cache_dir, read_states, write_states

log = logging.getLogger(__name__)

PROBE_KEYS = ("probes", "markers", "grid", "marker_points", "grid_points")


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
        model has no ``targets`` (:class:`~idbench.core.optional.TargetModel`)
        or none to show (T = 0).
    held_points
        A recording's held-out points per step (K, N, 3), NaN rows where a
        frame has fewer, scored by their distance to the model's surface; None
        without (every simulated truth).
    loads
        The truth model's load figures
        (:class:`~idbench.core.optional.LoadFiguresModel`), empty if it
        reports none: what each run's own are compared with.
    """

    states: FloatArray
    observations: FloatArray
    grid: FloatArray
    probes: dict[str, FloatArray]
    nodes: float = float("nan")
    targets: FloatArray | None = None
    held_points: FloatArray | None = None
    loads: dict[str, float] = field(default_factory=dict)


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
        if np.shape(state) != states.shape[1:]:
            raise ModelError(
                f"returned a state of shape {np.shape(state)} from step() at step "
                f"{k}; expected {states.shape[1:]}, the shape of its reset()",
                step=k,
            )
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
    figures = load_figures_of(model)
    return Truth(
        states=states,
        observations=np.array([model.observe(s) for s in states]),
        grid=np.array([model.grid(s) for s in states]),
        probes={name: np.array(values) for name, values in named.items()},
        nodes=float("nan") if nodes is None else float(nodes),
        targets=_targets(targets, states),
        loads={} if figures is None else {k: float(v) for k, v in figures().items()},
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
    states = read_states(path, key, shape) if cache else None
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
            write_states(path, key, states)
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
