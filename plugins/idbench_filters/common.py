"""What the estimators here share beyond :class:`idbench.Filter`.

The run scaffolding (run and step checks, cost, Diverged, transforms) is the
core's :class:`idbench.Filter`; this module holds this plugin's own policies:
the settings checks, the forward step with a sub-step retry (one at a time or
batched) and the observation Jacobian (the model's sensitivities, else finite
differences).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench import (
    Diverged,
    ForwardModel,
    IdentityTransform,
    ModelFailure,
    Observation,
    sensitivity_of,
)

FloatArray = NDArray[np.float64]

RETRY_SUBSTEPS = 4


def check_choice(name: str, value: Any, allowed: tuple[str, ...]) -> None:
    """Raise ValueError unless ``value`` is one of ``allowed``."""
    if value not in allowed:
        raise ValueError(
            f"{name} = {value!r} is not allowed; use one of "
            + ", ".join(repr(a) for a in allowed)
        )


def check_positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    """Raise ValueError unless ``value`` is finite and > 0 (>= 0 if allowed)."""
    ok = isinstance(value, int | float) and math.isfinite(value)
    ok = ok and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(
            f"{name} = {value!r} is not allowed; it must be finite {bound}"
        )


def advance(
    model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
) -> FloatArray:
    """One model step with a single retry in sub-steps.

    A :class:`ModelFailure` or a non-finite result is retried once with
    ``substeps=4``; if that fails too, :class:`Diverged` is raised at step k.
    """
    try:
        new = model.step(theta, k, state)
        if np.all(np.isfinite(new)):
            return np.asarray(new, dtype=float)
        first = "non-finite state"
    except ModelFailure as exc:
        first = str(exc)
    try:
        new = model.step(theta, k, state, substeps=RETRY_SUBSTEPS)
    except ModelFailure as exc:
        raise Diverged(
            f"forward solve failed at the parameter theta={theta}, from the "
            f"filter's state of step {k - 1} ({first}); retry with "
            f"{RETRY_SUBSTEPS} sub-steps failed too ({exc})",
            step=k,
        ) from exc
    if not np.all(np.isfinite(new)):
        raise Diverged(
            f"forward solve gave a non-finite state at the parameter "
            f"theta={theta}, from the filter's state of step {k - 1}",
            step=k,
        )
    return np.asarray(new, dtype=float)


def advance_many(
    model: ForwardModel, thetas: FloatArray, k: int, states: FloatArray
) -> FloatArray:
    """Advance r parameter/state pairs one load step: (r, p), (r, n) -> (r, n).

    Calls ``model.step_many`` (see :class:`idbench.BatchModel`) when the model
    has it; a row whose batched result is non-finite, or every row if the
    batched call raises :class:`~idbench.ModelFailure` (or the model has no
    ``step_many``), goes through :func:`advance` (``step`` with its sub-step
    retry), exactly as without batching.
    """
    step_many = getattr(model, "step_many", None)
    if step_many is not None:
        try:
            new = np.array(step_many(thetas, k, states), dtype=float)
        except ModelFailure:
            new = None
        if new is not None and new.shape == np.shape(states):
            for i in np.flatnonzero(~np.all(np.isfinite(new), axis=1)):
                new[i] = advance(model, thetas[i], k, states[i])
            return new
    return np.stack(
        [advance(model, thetas[i], k, states[i]) for i in range(len(thetas))]
    )


def observation_jacobian(
    model: ForwardModel,
    xi: FloatArray,
    k: int,
    state: FloatArray,
    prev_state: FloatArray,
    transform: IdentityTransform,
    fd_step: float,
) -> FloatArray:
    """J_xi = d observe / d xi (m, p) at the converged ``state`` of step k.

    Uses ``model.sensitivity`` when the model has it (J_xi = J_theta diag(dtheta/
    dxi)); otherwise forward finite differences in xi, each column one extra
    solve of step k from ``prev_state`` with xi_j + h, h = fd_step max(1, |xi_j|).
    """
    theta = transform.to_theta(xi)
    sensitivity = sensitivity_of(model)
    if sensitivity is not None:
        j_theta = np.asarray(sensitivity(theta, k, state), dtype=float)
        return j_theta * transform.dtheta_dxi(xi)[None, :]
    y0 = np.asarray(model.observe(state), dtype=float)
    cols = []
    for j in range(xi.size):
        h = fd_step * max(1.0, abs(float(xi[j])))
        xj = xi.copy()
        xj[j] += h
        uj = advance(model, transform.to_theta(xj), k, prev_state)
        cols.append((np.asarray(model.observe(uj), dtype=float) - y0) / h)
    return np.stack(cols, axis=1)


def advance_linearised(
    model: ForwardModel,
    xi: FloatArray,
    k: int,
    prev_state: FloatArray,
    transform: IdentityTransform,
    fd_step: float,
    observation: Observation | None,
) -> tuple[FloatArray, tuple[FloatArray, FloatArray] | None]:
    """One step of an estimator with one own state (RLS, LMS).

    Advances ``prev_state`` to step k with theta(xi) (:func:`advance`); if
    ``observation`` is given, linearises the observation map there.

    Returns
    -------
    tuple
        The new state and, if observed, ``(J, e)``: the Jacobian d observe /
        d xi (m, p) (:func:`observation_jacobian`) and the residual
        e = y - observe(state) (m,); else None.
    """
    state = advance(model, transform.to_theta(xi), k, prev_state)
    if observation is None:
        return state, None
    J = observation_jacobian(model, xi, k, state, prev_state, transform, fd_step)
    e = np.asarray(observation.values, dtype=float) - model.observe(state)
    return state, (J, e)
