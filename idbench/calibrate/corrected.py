"""The corrected model: the coarse model an estimator is handed, with its error.

Its observation carries the calibrated discrepancy
(:mod:`idbench.calibrate.discrepancy`, whose docstring has the maths); an
estimator that knows the correction reads the extra observation covariance
from it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idbench.calibrate.discrepancy import Discrepancy
from idbench.core.capabilities import member, present
from idbench.core.interfaces import Cost, FloatArray, ForwardModel


class CorrectedModel:
    """A coarse model whose observations carry the calibrated discrepancy.

    ``observe(state) = h_c(state) + mu(h_c(state))``, ``grid`` likewise with
    the grid discrepancy, ``sensitivity`` by the chain rule
    (I + d mu / d z) J_c, ``targets`` (once calibrated) with the targets'
    discrepancy; ``reset``, ``step`` and ``cost`` are the coarse model's, and
    ``describe`` is its description with the calibration's. Each prediction
    (``observe``, ``grid``, ``targets``) whose load state lies beyond the
    calibrated ones (:meth:`Discrepancy.extrapolates`) is counted in
    :attr:`extrapolated`. An
    estimator that knows it reads the extra observation covariance from
    :meth:`observation_cov` (``R + observation_cov(state)`` is its noise);
    one that does not still gets the corrected mean.

    Of the optional members (:data:`idbench.core.capabilities.OPTIONAL`) it
    has exactly those the coarse model has, looked up once, when wrapped,
    through :func:`idbench.core.capabilities.present`; each is the coarse
    model's own but for the two above. Nothing else of the coarse model is
    reachable from here but through :attr:`coarse`.

    Parameters
    ----------
    model
        The coarse forward model.
    discrepancy
        Its calibration.
    n_obs
        Observed steps of the run (the systematic error's weight, see
        :mod:`idbench.calibrate.discrepancy`).
    """

    def __init__(self, model: ForwardModel, discrepancy: Discrepancy,
                 n_obs: int = 1) -> None:  # fmt: skip
        self.coarse = model
        self.discrepancy = discrepancy
        self.n_obs = max(int(n_obs), 1)
        self.parameters = model.parameters
        self.n_steps = model.n_steps
        self.extrapolated = 0
        optional = present(model)
        if "sensitivity" in optional:
            optional["sensitivity"] = self._sensitivity
        if "targets" in optional and discrepancy.w_targets.size:
            optional["targets"] = self._targets
        for name, value in optional.items():
            setattr(self, name, value)

    def reset(self) -> FloatArray:
        """The coarse model's unloaded state."""
        return self.coarse.reset()

    def step(self, theta: FloatArray, k: int, state: FloatArray, *,
             substeps: int = 1) -> FloatArray:  # fmt: skip
        """The coarse model's step."""
        return self.coarse.step(theta, k, state, substeps=substeps)

    def observe(self, state: FloatArray) -> FloatArray:
        """h_c(state) + mu(h_c(state))."""
        z = self._load_state(state)
        return z + self.discrepancy.mean(z)

    def grid(self, state: FloatArray) -> FloatArray:
        """Coarse grid displacements plus the mean grid discrepancy."""
        g = np.asarray(self.coarse.grid(state), dtype=float)
        z = self._load_state(state)
        return g + self.discrepancy.mean_grid(z).reshape(g.shape)

    def _targets(self, state: FloatArray) -> FloatArray:
        """Coarse target displacements plus the mean targets' discrepancy."""
        moved = member(self.coarse, "targets")
        t: FloatArray = np.asarray(moved(state), dtype=np.float64)
        z = self._load_state(state)
        return np.asarray(t + self.discrepancy.mean_targets(z).reshape(t.shape))

    def _load_state(self, state: FloatArray) -> FloatArray:
        """The load state h_c(state) of a prediction; counted if it extrapolates.

        The unloaded state (z = 0, also what a shape is probed with) is not.
        """
        z = np.asarray(self.coarse.observe(state), dtype=float)
        if np.any(z) and self.discrepancy.extrapolates(z):
            self.extrapolated += 1
        return z

    def grid_cov(self, state: FloatArray) -> FloatArray:
        """The grid prediction's discrepancy covariance per point (G, d, d)."""
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return self.discrepancy.grid_cov(z)

    def targets_cov(self, state: FloatArray) -> FloatArray:
        """The targets' discrepancy covariance per target (T, 3, 3)."""
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return self.discrepancy.targets_cov(z)

    def observation_cov(self, state: FloatArray) -> FloatArray:
        """n_obs Sigma(h_c(state)) (m, m): the extra observation covariance."""
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return self.n_obs * self.discrepancy.cov(z)

    def _sensitivity(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        sens = member(self.coarse, "sensitivity")
        j = np.asarray(sens(theta, k, state), dtype=np.float64)
        z = np.asarray(self.coarse.observe(state), dtype=np.float64)
        return np.asarray(j + self.discrepancy.jacobian(z) @ j)

    def cost(self) -> Cost:
        """The coarse model's cost."""
        return self.coarse.cost()

    def describe(self) -> dict[str, Any]:
        """The coarse model's description with the calibration's."""
        return {**self.coarse.describe(), "correction": self.discrepancy.info}
