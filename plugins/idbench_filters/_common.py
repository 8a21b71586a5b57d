r"""Shared pieces of the estimators: parameter transform, guarded solves, checks.

Every estimator works on an unconstrained parameter vector xi (p,). With the
``"log"`` transform, xi = log(theta) and the Gaussian prior (mean E0, std s) in
natural units becomes the log-normal with the same mean and variance:

.. math::

    \mu_\xi = \ln E_0, \qquad \sigma_\xi^2 = \ln(1 + s^2 / E_0^2).

Estimates are reported as E = exp(mean xi) (the posterior median) with
E_std = E * std(xi). With ``"identity"``, xi = theta.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench import (
    Cost,
    Diverged,
    Estimate,
    ForwardModel,
    ModelFailure,
    Observation,
    Prior,
)

FloatArray = NDArray[np.float64]

TRANSFORMS = ("log", "identity")
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


def to_xi(theta: FloatArray, transform: str) -> FloatArray:
    """Natural parameters (p,) -> xi (p,)."""
    theta = np.asarray(theta, dtype=float)
    if transform == "log":
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(theta)
    return theta.copy()


def to_theta(xi: FloatArray, transform: str) -> FloatArray:
    """Xi (p,) -> natural parameters (p,)."""
    xi = np.asarray(xi, dtype=float)
    if transform == "log":
        with np.errstate(over="ignore"):
            return np.exp(xi)
    return xi.copy()


def dtheta_dxi(xi: FloatArray, transform: str) -> FloatArray:
    """Diagonal of d theta / d xi, shape (p,): theta for log, ones for identity."""
    return to_theta(xi, transform) if transform == "log" else np.ones_like(xi)


def prior_xi(prior: Prior, p: int, transform: str) -> tuple[FloatArray, FloatArray]:
    """Prior mean (p,) and covariance (p, p) of xi.

    Raises ValueError if the prior has the wrong length, or a non-positive mean
    under the log transform.
    """
    mean = np.asarray(prior.mean, dtype=float)
    std = np.asarray(prior.std, dtype=float)
    if mean.shape != (p,):
        raise ValueError(f"prior has {mean.size} entries but the model has p = {p}")
    if transform == "log":
        if np.any(mean <= 0):
            raise ValueError(
                f"the log transform needs a positive prior mean, got {mean}"
            )
        return np.log(mean), np.diag(np.log1p(std**2 / mean**2))
    return mean.copy(), np.diag(std**2)


def report(
    xi: FloatArray, cov_xi: FloatArray | None, transform: str
) -> tuple[FloatArray, FloatArray]:
    """Natural-unit mean and std (p,) from xi and its covariance (NaN std if None)."""
    theta = to_theta(xi, transform)
    if cov_xi is None:
        return theta, np.full_like(theta, np.nan)
    with np.errstate(invalid="ignore"):
        std_xi = np.sqrt(np.diag(cov_xi))
    return theta, (theta * std_xi if transform == "log" else std_xi)


def noise_var(observation: Observation, sigma_floor: float) -> float:
    """Observation noise variance R_ii = max(noise_std, sigma_floor)^2."""
    return float(max(observation.noise_std, sigma_floor)) ** 2


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
            f"forward solve failed at theta={theta} ({first}); "
            f"retry with {RETRY_SUBSTEPS} sub-steps failed too ({exc})",
            step=k,
        ) from exc
    if not np.all(np.isfinite(new)):
        raise Diverged(
            f"forward solve gave a non-finite state at theta={theta}", step=k
        )
    return np.asarray(new, dtype=float)


def observation_jacobian(
    model: ForwardModel,
    xi: FloatArray,
    k: int,
    state: FloatArray,
    prev_state: FloatArray,
    transform: str,
    fd_step: float,
) -> FloatArray:
    """J_xi = d observe / d xi (m, p) at the converged ``state`` of step k.

    Uses ``model.sensitivity`` when the model has it (J_xi = J_theta diag(dtheta/
    dxi)); otherwise forward finite differences in xi, each column one extra
    solve of step k from ``prev_state`` with xi_j + h, h = fd_step max(1, |xi_j|).
    """
    theta = to_theta(xi, transform)
    if hasattr(model, "sensitivity"):
        j_theta = np.asarray(model.sensitivity(theta, k, state), dtype=float)
        return j_theta * dtheta_dxi(xi, transform)[None, :]
    y0 = np.asarray(model.observe(state), dtype=float)
    cols = []
    for j in range(xi.size):
        h = fd_step * max(1.0, abs(float(xi[j])))
        xj = xi.copy()
        xj[j] += h
        uj = advance(model, to_theta(xj, transform), k, prev_state)
        cols.append((np.asarray(model.observe(uj), dtype=float) - y0) / h)
    return np.stack(cols, axis=1)


def check_estimate(
    model: ForwardModel, xi: FloatArray, k: int, transform: str, *extra: FloatArray
) -> None:
    """Raise :class:`Diverged` at step k if theta is non-finite or out of bounds.

    ``extra`` arrays (covariances, states) must be finite too.
    """
    theta = to_theta(xi, transform)
    if not np.all(np.isfinite(theta)):
        raise Diverged(f"non-finite estimate {theta}", step=k)
    for arr in extra:
        if not np.all(np.isfinite(arr)):
            raise Diverged("non-finite covariance or state", step=k)
    spec = model.parameters
    if not spec.contains(theta):
        raise Diverged(
            f"estimate {theta} left the bounds [{spec.lower}, {spec.upper}]", step=k
        )


def check_step(k: int, observation: Observation | None, n_steps: int) -> None:
    """Raise ValueError if k is outside 1..K or the observation is for another step."""
    if not 1 <= k <= n_steps:
        raise ValueError(f"step k = {k} is outside 1..{n_steps}")
    if observation is not None and observation.step != k:
        raise ValueError(f"observation for step {observation.step} given at step {k}")


@dataclass
class RunState:
    """What every estimator keeps about its current run."""

    model: ForwardModel
    cost0: Cost

    def estimate(
        self,
        xi: FloatArray,
        cov_xi: FloatArray | None,
        transform: str,
        state: FloatArray | None,
    ) -> Estimate:
        """Build the reported :class:`Estimate` (cost since start)."""
        mean, std = report(xi, cov_xi, transform)
        return Estimate(
            mean=mean,
            std=std,
            cost=self.model.cost() - self.cost0,
            state=None if state is None else np.array(state, dtype=float),
        )


@dataclass
class Settings:
    """The settings every estimator here starts with, checked once.

    Attributes
    ----------
    transform
        ``"log"`` (xi = ln theta, default) or ``"identity"``.
    sigma_floor
        Lower bound (m) on the observation noise std used in R.
    """

    transform: str = "log"
    sigma_floor: float = 1e-6
    _run: RunState | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        check_choice("transform", self.transform, TRANSFORMS)
        check_positive("sigma_floor", self.sigma_floor)
