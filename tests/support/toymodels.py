"""Small forward models implementing idbench's protocol, for the estimator tests.

- :class:`LinearToy`: u_k = (k/K) A theta, observe = H u: linear-Gaussian, so the
  Kalman filter / least squares answers are known in closed form.
- :class:`InverseToy`: u_k = (k/K) A (1/theta), a stiffness-like nonlinear map
  (displacement ~ load / modulus) for the log-transform tests.
- :class:`FailingToy`: raises ModelFailure or returns NaN at a chosen step.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idbench import Cost, ModelFailure, ParameterSpec


class _Toy:
    """Common bookkeeping: reset, observe, grid, cost, describe."""

    def __init__(
        self,
        p: int = 1,
        n: int = 4,
        m: int = 3,
        n_steps: int = 6,
        seed: int = 0,
        lower: float = -1e6,
        upper: float = 1e6,
    ) -> None:
        rng = np.random.default_rng(seed)
        self.A = rng.normal(size=(n, p))
        self.H = rng.normal(size=(m, n))
        self.n_steps = n_steps
        names = ("E",) if p == 1 else tuple(f"E_region{i}" for i in range(p))
        self.parameters = ParameterSpec(names, (lower,) * p, (upper,) * p)
        self._solves = 0
        self._its = 0
        self._lin = 0
        self.calls: list[tuple[int, int]] = []  # (k, substeps) per step call

    def reset(self) -> np.ndarray:
        return np.zeros(self.A.shape[0])

    def observe(self, state: np.ndarray) -> np.ndarray:
        return self.H @ state

    def grid(self, state: np.ndarray) -> np.ndarray:
        return np.resize(state, (2, 3))

    def cost(self) -> Cost:
        return Cost(self._solves, self._its, self._lin)

    def describe(self) -> dict[str, Any]:
        return {"model": type(self).__name__, "A": self.A.tolist()}

    def _count(self, k: int, substeps: int) -> None:
        self._solves += 1
        self._its += substeps
        self._lin += substeps
        self.calls.append((k, substeps))


class LinearToy(_Toy):
    """u_k = (k/K) A theta; exact sensitivity (k/K) H A. No sensitivity if plain."""

    def step(
        self, theta: np.ndarray, k: int, state: np.ndarray, *, substeps: int = 1
    ) -> np.ndarray:
        self._count(k, substeps)
        return (k / self.n_steps) * self.A @ np.asarray(theta, dtype=float)

    def jac(self, k: int) -> np.ndarray:
        """D observe(u_k) / d theta, (m, p)."""
        return (k / self.n_steps) * self.H @ self.A


class SensitiveLinearToy(LinearToy):
    def sensitivity(self, theta: np.ndarray, k: int, state: np.ndarray) -> np.ndarray:
        self._lin += len(theta)
        return self.jac(k)


class InverseToy(_Toy):
    """u_k = (k/K) A (1/theta) with positive A: displacement ~ load / stiffness."""

    def __init__(self, p: int = 1, **kw: Any) -> None:
        kw.setdefault("lower", 1.0)
        kw.setdefault("upper", 1e7)
        super().__init__(p=p, **kw)
        self.A = np.abs(self.A) + 0.5

    def step(
        self, theta: np.ndarray, k: int, state: np.ndarray, *, substeps: int = 1
    ) -> np.ndarray:
        self._count(k, substeps)
        return (k / self.n_steps) * self.A @ (1.0 / np.asarray(theta, dtype=float))

    def sensitivity(self, theta: np.ndarray, k: int, state: np.ndarray) -> np.ndarray:
        self._lin += len(theta)
        theta = np.asarray(theta, dtype=float)
        return -(k / self.n_steps) * self.H @ self.A / theta**2


class FailingToy(InverseToy):
    """Fails at step ``fail_at``.

    mode: ``"raise"`` always raises ModelFailure there; ``"nan"`` returns NaN;
    ``"once"`` raises only without sub-steps (the retry succeeds).
    """

    def __init__(self, fail_at: int, mode: str = "raise", **kw: Any) -> None:
        super().__init__(**kw)
        self.fail_at = fail_at
        self.mode = mode

    def step(
        self, theta: np.ndarray, k: int, state: np.ndarray, *, substeps: int = 1
    ) -> np.ndarray:
        u = super().step(theta, k, state, substeps=substeps)
        if k == self.fail_at:
            if self.mode == "nan":
                return np.full_like(u, np.nan)
            if self.mode == "raise" or substeps == 1:
                raise ModelFailure("Newton did not converge", step=k)
        return u


def simulate(model: _Toy, theta: np.ndarray) -> list[np.ndarray]:
    """Noise-free observations at steps 1..K (does not touch the model's cost)."""
    cost = (model._solves, model._its, model._lin, list(model.calls))
    u = model.reset()
    ys = []
    for k in range(1, model.n_steps + 1):
        u = model.step(np.asarray(theta, dtype=float), k, u)
        ys.append(model.observe(u))
    model._solves, model._its, model._lin, model.calls = cost
    return ys


class BatchedToy(LinearToy):
    """Linear toy with ``step_many``, counting batched calls."""

    def __init__(self, *a, fail_rows=(), **kw):
        super().__init__(*a, **kw)
        self.batched = 0
        self.fail_rows = set(fail_rows)

    def step_many(self, thetas, k, states):
        self.batched += 1
        out = np.stack(
            [self.step(t, k, s) for t, s in zip(thetas, states, strict=True)]
        )
        for i in self.fail_rows:
            out[i] = np.nan
        return out


class LinearFieldToy(LinearToy):
    """LinearToy whose p parameters are a field on a chain of cells along x.

    It has the members field estimators need: ``parameter_field`` (cells of
    unit volume at x = 0, 1, ..., p - 1, neighbours sharing unit area),
    ``equilibrium_jvp`` / ``equilibrium_vjp`` (du_k/dtheta = (k/K) A),
    ``observation_jacobian`` (H, 0) and ``observation_points`` (the m values
    spread along the chain).
    """

    def __init__(self, p: int = 12, length: float = 3.0, **kw: Any) -> None:
        super().__init__(p=p, **kw)
        from idbench import ParameterField

        x = np.arange(p, dtype=float)
        self.parameter_field = ParameterField(
            np.stack([x, 0 * x, 0 * x], axis=1), np.ones(p),
            np.stack([np.arange(p - 1), np.arange(1, p)], axis=1), np.ones(p - 1),
            length,
        )  # fmt: skip
        m = self.H.shape[0]
        self._points = np.stack(
            [np.linspace(0, p - 1, m), np.zeros(m), np.zeros(m)], axis=1
        )

    def equilibrium_jvp(self, theta, k, state, v):
        self._lin += 1
        return (k / self.n_steps) * self.A @ np.asarray(v, dtype=float)

    def equilibrium_vjp(self, theta, k, state, w):
        self._lin += 1
        return (k / self.n_steps) * self.A.T @ np.asarray(w, dtype=float)

    def observation_jacobian(self, theta, k, state):
        return self.H, np.zeros((self.H.shape[0], len(theta)))

    def observation_points(self, k):
        return self._points
