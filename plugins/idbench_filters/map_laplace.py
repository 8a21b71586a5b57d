r"""MAP over the whole path with adjoint gradients, and a low-rank Laplace posterior.

The batch estimator of parameter fields (hIPPYlib's recipe on a hyperelastic
path): with x = ln theta (``transform = "log"``), a Gaussian prior
N(mu, Sigma = F F^T) (the smoothness prior of the model's
:class:`idbench.ParameterField`, :mod:`idbench.estimate.prior`, else the
comparison's independent one) and the observations y_k of the observed
steps,

.. math::

    J(x) = \tfrac12 \sum_k \|y_k - h_k(u_k(x))\|^2_{R_k^{-1}}
         + \tfrac12 \|x - \mu\|^2_{\Sigma^{-1}}.

**Gradient (adjoint).** With dead loads and a hyperelastic law each step's
equilibrium r(u_k, theta) = 0 is its own problem, so one forward path and
one transposed solve per observed step give it: with
(H_u, H_theta) the linearized observation (:class:`idbench.LinearObservationModel`)
and w_k = R_k^-1 r_k, r_k = y_k - h_k,

.. math::

    K_k^T \lambda_k = H_u^T w_k, \qquad
    \frac{dJ}{d\theta} = -\sum_k \left(-\lambda_k^T G_k + H_\theta^T w_k\right),

G_k = dr/dtheta (:class:`idbench.AdjointModel`'s ``equilibrium_vjp``);
times dtheta/dx for x.

**Gauss-Newton.** In whitened coordinates x = mu + F z the GN system is
(I + A^T A) dz = -grad_z, A the stacked R^{-1/2} J_k F, J_k = dh_k/dx
formed per observed step by p forward products (one multi-column solve with
the step's factorization) or, when the step has fewer values m_k than p, by
m_k adjoint products (``jacobian``); a backtracking (Armijo) line search,
stopping when the step's largest whitened component is below ``tol`` (prior
standard deviations) or after ``max_iterations``.

**Laplace.** At the MAP point the posterior is N(x_map, F (I + H_d)^-1 F^T),
H_d = A^T A, from the ``rank`` largest eigenpairs of H_d by a randomized
eigensolver (:mod:`idbench_filters.laplace`); exact when ``rank`` reaches p.

It fits once, at the last step K, and reports the prior before (as
``batch-ls``'s default ``refit = "end"``). It needs a model with the adjoint
and observation Jacobian members (the ``solid`` model, markers, cloud and
force observations); others are skipped, saying why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from idbench import (
    Analysis,
    Diverged,
    FieldPrior,
    Filter,
    ForwardModel,
    MaskedModel,
    Observation,
    Prior,
    Skipped,
    adjoint_of,
    observation_jacobian_of,
    parameter_field_of,
)
from idbench_filters.common import FloatArray, advance, check_choice, check_positive
from idbench_filters.laplace import LaplacePosterior, laplace

JACOBIANS = ("auto", "forward", "adjoint")
ARMIJO = 1e-4
HALVINGS = 6


@dataclass(frozen=True)
class Evaluation:
    """J at one point: its value, gradient (x), whitened Jacobian, final state."""

    cost: float
    gradient: FloatArray | None
    rows: FloatArray | None
    state: FloatArray


@dataclass
class MapLaplace(Filter):
    """MAP estimate by adjoint Gauss-Newton, with a low-rank Laplace posterior.

    Attributes
    ----------
    length
        The prior's correlation length (m); None: the model's field's.
    std
        The prior's std of ln theta; None: the field's, else the comparison's.
    max_iterations
        Gauss-Newton iterations at most (each one forward path with the
        Jacobian, plus one a backtracking halving).
    tol
        Stop when the largest component of the whitened step is below this
        (prior standard deviations).
    rank
        Eigenpairs of the Laplace approximation (None: p, exact).
    jacobian
        ``"forward"`` (p products a step), ``"adjoint"`` (m products a step)
        or ``"auto"`` (the fewer).
    seed
        Of the randomized eigensolver.
    """

    by_default: ClassVar[bool] = False  # for fields: name it

    length: float | None = None
    std: float | None = None
    max_iterations: int = 10
    tol: float = 1e-2
    rank: int | None = None
    jacobian: str = "auto"
    seed: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("length", "std"):
            if getattr(self, name) is not None:
                check_positive(name, getattr(self, name))
        check_positive("tol", self.tol)
        for name in ("max_iterations", "rank"):
            n = getattr(self, name)
            if n is not None and (isinstance(n, bool) or not isinstance(n, int)
                                  or n < 1):  # fmt: skip
                raise ValueError(f"{name} = {n!r} is not allowed; use an integer >= 1")
        check_choice("jacobian", self.jacobian, JACOBIANS)

    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        """About half the iterations' forward paths of K steps."""
        return (self.max_iterations // 2 + 1) * steps

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run: the prior; no observation yet.

        Raises
        ------
        Skipped
            A model without the adjoint or the observation Jacobian, or a
            corrected run.
        """
        if adjoint_of(model) is None or observation_jacobian_of(model) is None:
            raise Skipped(
                "map-laplace needs a model with equilibrium_jvp, equilibrium_vjp "
                "and observation_jacobian (adjoint gradients)"
            )
        if self.correction == "approximation-error":
            raise Skipped("map-laplace has no approximation-error correction")
        mu, cov = self.prior_xi(prior)
        field = parameter_field_of(model)
        if field is None:
            std = self.std if self.std is not None else np.sqrt(np.diag(cov))
            F = np.diag(np.broadcast_to(std, mu.shape).astype(float))
            self.field_prior = FieldPrior(mu, F, np.eye(mu.size), np.diag(F).copy())
        else:
            std = self.std or field.std or np.sqrt(np.diag(cov))
            self.field_prior = FieldPrior.of(field, mu, std, self.length)
        self._xi, self._cov = mu.copy(), self.field_prior.cov
        self._obs: dict[int, tuple[FloatArray, FloatArray, Any]] = {}
        self.posterior: LaplacePosterior | None = None
        self.iterations = 0

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Keep the observation; at step K fit the MAP and its Laplace posterior."""
        if observation is not None:
            y = np.asarray(observation.values, dtype=float)
            var = np.broadcast_to(self.noise_var(observation), y.shape)
            mask = self.visible
            view = self.run.model if mask is None else MaskedModel(self.run.model, mask)  # type: ignore[arg-type]
            self._obs[k] = (y, 1.0 / np.asarray(var, dtype=float), view)
        state = None
        if k == self.run.model.n_steps and self._obs:
            state = self._fit(k)
        return Analysis(self._xi, self._cov, state)

    # --- the fit -------------------------------------------------------------

    def evaluate(self, xi: FloatArray, jacobian: bool = True) -> Evaluation:
        """J(xi), and with ``jacobian`` its adjoint gradient and whitened rows.

        The rows A (sum m_k, p) are R^{-1/2} dh/dx F (z coordinates).
        """
        model = self.run.model
        theta = self.to_theta(xi)
        scale = self.dtheta_dxi(xi)
        adjoint = adjoint_of(model)
        assert adjoint is not None
        u = np.asarray(model.reset(), dtype=float)
        cost, grad, rows = 0.0, np.zeros(xi.size), []
        for k in range(1, max(self._obs) + 1):
            u = advance(model, theta, k, u)
            if k not in self._obs:
                continue
            y, rinv, view = self._obs[k]
            r = y - np.asarray(view.observe(u), dtype=float)
            cost += 0.5 * float(r @ (rinv * r))
            if not jacobian:
                continue
            hu, ht = observation_jacobian_of(view)(theta, k, u)  # type: ignore[misc]
            hu = sp.csr_matrix(hu)
            w = rinv * r
            dh_w = adjoint.equilibrium_vjp(theta, k, u, hu.T @ w) + ht.T @ w
            grad -= dh_w * scale
            J = self._dh_dtheta(adjoint, theta, k, u, hu, ht) * scale
            rows.append(np.sqrt(rinv)[:, None] * J)
        cost += self.field_prior.energy(xi)
        if not jacobian:
            return Evaluation(cost, None, None, u)
        grad += self.field_prior.gradient(xi)
        A = np.vstack(rows) @ self.field_prior.factor
        return Evaluation(cost, grad, A, u)

    def _dh_dtheta(
        self, adjoint: Any, theta: FloatArray, k: int, u: FloatArray, hu: Any,
        ht: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """dh/dtheta (m, p) at step k: forward (p columns) or adjoint (m rows)."""
        m, p = hu.shape[0], theta.size
        forward = self.jacobian == "forward" or (self.jacobian == "auto" and p <= m)
        if forward:
            du = adjoint.equilibrium_jvp(theta, k, u, np.eye(p))
            return np.asarray(hu @ du + ht)
        rows = adjoint.equilibrium_vjp(theta, k, u, hu.T.toarray())  # (p, m)
        return np.asarray(rows.T + ht)

    def _fit(self, k: int) -> FloatArray:
        """Gauss-Newton from the prior mean; the Laplace posterior at its end."""
        F = self.field_prior.factor
        xi = self.field_prior.mean.copy()
        at = self.evaluate(xi)
        for it in range(self.max_iterations):
            assert at.gradient is not None and at.rows is not None
            A = at.rows
            g = F.T @ at.gradient
            dz = -np.linalg.solve(np.eye(xi.size) + A.T @ A, g)
            alpha, found = 1.0, None
            for _ in range(HALVINGS + 1):
                trial = xi + alpha * (F @ dz)
                try:
                    new = self.evaluate(trial, jacobian=alpha == 1.0)
                except Diverged:
                    new = None
                if new is not None and new.cost <= at.cost + ARMIJO * alpha * (g @ dz):
                    found = (trial, new)
                    break
                alpha /= 2
            self.iterations = it + 1
            if found is None:  # no descent: the GN point is as good as it gets
                break
            xi, at = found
            if at.rows is None:
                at = self.evaluate(xi)
            if alpha * np.max(np.abs(dz)) < self.tol:
                break
        assert at.rows is not None
        A = at.rows
        rank = xi.size if self.rank is None else self.rank
        rng = np.random.default_rng(self.seed)
        self.posterior = laplace(xi, F, lambda X: A.T @ (A @ X), rank, rng)
        self._xi, self._cov = xi, self.posterior.cov
        return at.state
