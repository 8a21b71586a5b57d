"""What every estimator here shares: the run scaffolding, guarded solves, checks.

:class:`Settings` is the base of every estimator (as DAPPER's ``da_method``
wrapper): it owns ``start`` and ``update`` and does, once for all, the run
check, the step check, the cost bookkeeping, the turning of a failed linear
solve into :class:`~idbench.Diverged` and the final finite/bounds check, so
each estimator writes only its maths in ``begin`` and ``assimilate``. The
parameter transforms (xi = ln theta or theta) are objects in
:mod:`idbench_filters.transforms`.
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
from idbench_filters.transforms import TRANSFORMS
from idbench_filters.transforms import prior_xi as _prior_xi

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


def to_xi(theta: FloatArray, transform: str) -> FloatArray:
    """Natural parameters (p,) -> xi (p,), in the named transform."""
    return TRANSFORMS[transform].to_xi(theta)


def to_theta(xi: FloatArray, transform: str) -> FloatArray:
    """Xi (p,) -> natural parameters (p,), in the named transform."""
    return TRANSFORMS[transform].to_theta(xi)


def dtheta_dxi(xi: FloatArray, transform: str) -> FloatArray:
    """Diagonal of d theta / d xi, shape (p,), in the named transform."""
    return TRANSFORMS[transform].dtheta_dxi(xi)


def prior_xi(prior: Prior, p: int, transform: str) -> tuple[FloatArray, FloatArray]:
    """Prior mean (p,) and covariance (p, p) of xi (see :mod:`.transforms`)."""
    return _prior_xi(prior, p, TRANSFORMS[transform])


def report(
    xi: FloatArray, cov_xi: FloatArray | None, transform: str
) -> tuple[FloatArray, FloatArray]:
    """Natural-unit mean and std (p,) from xi and its covariance (NaN std if None)."""
    t = TRANSFORMS[transform]
    theta = t.to_theta(xi)
    if cov_xi is None:
        return theta, np.full_like(theta, np.nan)
    with np.errstate(invalid="ignore"):
        std_xi = np.sqrt(np.diag(cov_xi))
    return theta, t.std(theta, std_xi)


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


@dataclass(frozen=True)
class Step:
    """What an estimator's :meth:`Settings.assimilate` returns for one step.

    Attributes
    ----------
    xi
        Parameter estimate in the transformed space, (p,).
    cov
        Its covariance (p, p), or None if the estimator has none.
    state
        The estimator's own model state at this step, or None.
    finite
        Further arrays that must be finite (covariances, ensembles).
    """

    xi: FloatArray
    cov: FloatArray | None = None
    state: FloatArray | None = None
    finite: tuple[FloatArray, ...] = ()


@dataclass
class Settings:
    """The base of every estimator here: shared settings and the run scaffolding.

    Subclasses implement ``begin(model, prior)`` (set up the run's state) and
    ``assimilate(k, observation) -> Step`` (advance to step k, assimilate).

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
        check_choice("transform", self.transform, tuple(TRANSFORMS))
        check_positive("sigma_floor", self.sigma_floor)

    @property
    def run(self) -> RunState:
        """The current run (RuntimeError before :meth:`start`)."""
        if self._run is None:
            raise RuntimeError("call start() before update()")
        return self._run

    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        """Forward model steps a run is expected to take: one a load step.

        That is the gradient filters' own path with the model's sensitivities
        (finite differences, for a model without them, add p a step); the
        other estimators say what they cost. A guess, for planning only.
        """
        return steps

    def start(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run on ``model`` from ``prior`` (cost counted from here)."""
        self._run = RunState(model, model.cost())
        self.begin(model, prior)

    def update(self, k: int, observation: Observation | None) -> Estimate:
        """Advance to load step ``k`` and assimilate ``observation`` if any.

        Raises
        ------
        Diverged
            A linear solve failed, or the estimate is non-finite or out of bounds.
        """
        run = self.run
        check_step(k, observation, run.model.n_steps)
        try:
            step = self.assimilate(k, observation)
        except np.linalg.LinAlgError as exc:
            raise Diverged(f"linear algebra failed: {exc}", step=k) from exc
        check_estimate(run.model, step.xi, k, self.transform, *step.finite)
        return run.estimate(step.xi, step.cov, self.transform, step.state)

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Set up the run's own state (the estimator's part of :meth:`start`)."""
        raise NotImplementedError

    def assimilate(self, k: int, observation: Observation | None) -> Step:
        """Advance to step ``k``, assimilate ``observation``; the new estimate."""
        raise NotImplementedError
