"""Effective parameters per load level: the best constant fit at each step.

A coarse P1 mesh is too stiff, and by how much depends on the deformation. The
*effective* parameter at load step k is the constant theta for which the model,
in equilibrium under step k's load, best matches a target displacement field
(by default the truth's shape-error grid, noise-free) in the least-squares
sense. Hyperelastic bodies under dead loads are path independent, so the
equilibrium at step k depends on theta only, not on how it was reached; that
makes the fit per load level well defined and cheap to continue from step to
step.

The fit is Gauss-Newton on xi = log theta with a forward-difference Jacobian
(one extra warm-started solve per parameter and iteration), so it needs only
the :class:`~idbench.core.interfaces.ForwardModel` protocol.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from idbench.core.interfaces import FloatArray, ForwardModel, ModelFailure

Target = Literal["grid", "observations"]

#: Relative step of the forward-difference Jacobian in log theta.
FD_STEP = 1e-4
#: Largest Gauss-Newton update of log theta per iteration (a factor e^0.5).
MAX_UPDATE = 0.5


@dataclass(frozen=True)
class EffectivePath:
    """Effective parameters along a load path.

    Attributes
    ----------
    theta
        Best constant parameters per step, shape (K, p).
    residual
        Root-mean-square misfit per step at ``theta`` (m), over the target's
        components (not per-point distances), shape (K,).
    iterations
        Gauss-Newton iterations per step, shape (K,).
    states
        Model equilibrium states at ``theta`` per step, shape (K, n).
    """

    theta: FloatArray
    residual: FloatArray
    iterations: NDArray[np.int64]
    states: FloatArray


def effective_path(
    model: ForwardModel,
    target: FloatArray,
    theta0: FloatArray,
    *,
    using: Target = "grid",
    tol: float = 1e-6,
    max_iterations: int = 20,
) -> EffectivePath:
    """Fit the best constant parameters at every load step of ``model``.

    Parameters
    ----------
    model
        The (coarse) model; its scenario and ``n_steps`` define the load levels.
    target
        Displacements to match per step: ``(K, G, 3)`` grid displacements when
        ``using="grid"``, ``(K, m)`` marker displacements when
        ``using="observations"``. Usually the truth's ``grid`` or
        ``observations``, probed at the same points as ``model``.
    theta0
        Starting parameters (p,), e.g. E_true; step k starts from step k-1's fit.
    using
        Which displacements of the model to compare with ``target``.
    tol
        Convergence tolerance on the update of log theta.
    max_iterations
        Gauss-Newton iterations per step before giving up.

    Returns
    -------
    EffectivePath

    Raises
    ------
    ValueError
        ``target`` does not have one entry per load step, or ``using`` is
        neither ``"grid"`` nor ``"observations"``.
    ModelFailure
        The model fails to converge even with load sub-steps, or the fit does
        not converge within ``max_iterations`` at some step.
    """
    probe = _prober(model, using)
    target = np.asarray(target, dtype=float)
    n_steps = model.n_steps
    if target.shape[0] != n_steps:
        raise ValueError(
            f"target has {target.shape[0]} steps, the model has {n_steps}"
        )
    flat = target.reshape(n_steps, -1)
    xi = np.log(np.atleast_1d(np.asarray(theta0, dtype=float)))
    p = xi.size
    base = model.reset()
    thetas = np.empty((n_steps, p))
    residuals = np.empty(n_steps)
    iterations = np.zeros(n_steps, dtype=int)
    states = np.empty((n_steps, base.size))
    for k in range(1, n_steps + 1):
        u = _solve(model, np.exp(xi), k, base)
        for it in range(1, max_iterations + 1):
            at_u = probe(u)
            r = at_u - flat[k - 1]
            jac = np.empty((r.size, p))
            for j in range(p):
                xj = xi.copy()
                xj[j] += FD_STEP
                jac[:, j] = (probe(_solve(model, np.exp(xj), k, u)) - at_u) / FD_STEP
            dxi = np.linalg.lstsq(jac, -r, rcond=None)[0]
            dxi = np.clip(dxi, -MAX_UPDATE, MAX_UPDATE)
            xi = xi + dxi
            u = _solve(model, np.exp(xi), k, u)
            iterations[k - 1] = it
            if np.max(np.abs(dxi)) < tol:
                break
        else:
            raise ModelFailure(
                f"effective fit did not converge in {max_iterations} iterations",
                step=k,
            )
        thetas[k - 1] = np.exp(xi)
        residuals[k - 1] = float(np.sqrt(np.mean((probe(u) - flat[k - 1]) ** 2)))
        states[k - 1] = u
        base = u
    return EffectivePath(thetas, residuals, iterations, states)


def _prober(model: ForwardModel, using: str) -> Callable[[FloatArray], FloatArray]:
    if using == "grid":
        return lambda u: np.ravel(model.grid(u))
    if using == "observations":
        return lambda u: np.ravel(model.observe(u))
    raise ValueError(f"using = {using!r}: must be 'grid' or 'observations'")


def _solve(
    model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
) -> FloatArray:
    """Equilibrium at step ``k`` from ``state``; retried in load sub-steps."""
    try:
        return model.step(theta, k, state)
    except ModelFailure:
        return model.step(theta, k, state, substeps=8)
