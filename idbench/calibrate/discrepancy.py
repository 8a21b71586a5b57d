r"""The approximation error of a coarse mesh: the fitted discrepancy.

The Bayesian approximation error approach (Kaipio & Somersalo 2007): a
coarse model h_c is a fine model h_f plus a discrepancy,

.. math::

    y = h_f(u_f(\theta)) + e = h_c(u_c(\theta)) + d(\theta) + e, \qquad
    d = h_f(u_f) - h_c(u_c),

and d, sampled offline over the prior with the fine and the coarse model of
the same body (never the comparison's truth data; the design:
:mod:`idbench.calibrate.design`), is modelled as Gaussian.
Here it is conditioned on the *load state*, which the coarse model's own
predicted observation z = h_c(u_c) represents (for one load direction the
load state, the step and theta enter only through it). Over the samples
(z_i, d_i), a weighted ridge regression on the features phi(z) (``"linear"``:
1, z; ``"quadratic"``: also every z_a z_b) gives the mean
mu(z) = W^T phi(z); its residuals, modelled as relative to the displacement
(variance C (t_i + t_0), t = |z|^2 / z_s^2, z_s the RMS sample |z|, weights
w_i = 1 / (t_i + t_0)), give the covariance of a prediction,

.. math::

    \Sigma(z) = C \, \big(t(z) + t_0 + h(z)\big), \qquad
    h(z) = \phi(z)^T (\Phi^T W \Phi)^{-1} \phi(z),

C the larger of the in-sample and the leave-one-scenario-out residual
covariance (see :func:`idbench.calibrate.fit.fit`), the leverage h growing
where z leaves the calibrated load states (a load
direction the design did not span): there the correction extrapolates, and
:meth:`Discrepancy.extrapolates` says so. The corrected observation model an
estimator uses (:class:`idbench.calibrate.corrected.CorrectedModel`) is

.. math::

    y = h_c(x) + \mu(h_c(x)) + e, \qquad e \sim N(0, R + n_{obs} \Sigma(h_c(x))).

The factor n_obs (the observed steps of the run): the discrepancy is the
same systematic error at every step, not fresh noise; for an error shared by
n observations, n independent ones of n times its covariance carry the same
information about theta (exact for a linear model with a constant error).

The same regression (the same features and weights) gives the mean
discrepancy of the shape-error grid and of the hidden targets (a model with
``targets``), and per grid point and per target a residual covariance
(3 x 3, from the same in-sample or leave-one-scenario-out residuals as C)
that grows with z like Sigma: the predictive uncertainty of a corrected
shape is the parameter's propagated covariance plus this one
(:func:`idbench.score.targets.grid_columns`).

The fitted :class:`Discrepancy` is cached on disk like the truth
(:mod:`idbench.truth.cache`'s folder, a hash of both models' descriptions, the
prior, the settings and the version; atomic writes, a content digest
checked on load), and so are its fine paths (as truths).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from idbench.core.interfaces import FloatArray
from idbench.store.files import digest
from idbench.truth.cache import read_entry, write_entry

FEATURES = ("linear", "quadratic")
"""The feature kinds of :func:`feature_matrix`."""

FLOOR = 1e-4
"""t_0: the residual variance floor, relative to the squared RMS sample |z|."""

FIT_VERSION = 3
"""Changes when the fit changes (the cache keys on it); 2: C from the
leave-one-scenario-out residuals where they interpolate; 3: the targets'
discrepancy and the grid's and targets' residual covariances."""


def feature_matrix(z: FloatArray, scale: float, kind: str) -> FloatArray:
    """phi(z) (n, F) of observations z (n, m), scaled by ``scale``."""
    x = np.atleast_2d(z) / scale
    cols = [np.ones((x.shape[0], 1)), x]
    if kind == "quadratic":
        a, b = np.triu_indices(x.shape[1])
        cols.append(x[:, a] * x[:, b])
    return np.hstack(cols)


def _feature_jacobian(z: FloatArray, scale: float, kind: str) -> FloatArray:
    """The feature Jacobian d phi / d z (F, m) at one observation z (m,)."""
    m = z.size
    x = z / scale
    rows = [np.zeros((1, m)), np.eye(m) / scale]
    if kind == "quadratic":
        a, b = np.triu_indices(m)
        jq = np.zeros((a.size, m))
        jq[np.arange(a.size), a] += x[b] / scale
        jq[np.arange(a.size), b] += x[a] / scale
        rows.append(jq)
    return np.vstack(rows)


@dataclass(frozen=True)
class Discrepancy:
    """A coarse mesh's approximation error as a function of its observation.

    Attributes
    ----------
    features
        ``"linear"`` or ``"quadratic"``.
    scale
        z_s, the RMS |z| of the samples (features use z / z_s).
    w_obs
        Regression weights (F, m) of the marker discrepancy.
    w_grid
        Regression weights (F, G d) of the shape-error grid discrepancy.
    cov_unit
        C (m, m), the weighted residual covariance.
    w_targets
        Regression weights (F, 3 T) of the hidden targets' discrepancy
        (T = 0: the model has no targets).
    cov_grid
        Per grid point, its residual covariance (G, d, d), like C.
    cov_targets
        Per target, its residual covariance (T, 3, 3), like C.
    a_inv
        (Phi^T W Phi + ridge)^-1 (F, F), for the prediction variance and the
        leverage.
    floor
        t_0, the relative floor of the residual variance.
    leverage_max
        The largest leverage of a sample: a z beyond it extrapolates.
    cost
        Fine path simulations the calibration took (fine steps / K).
    info
        What it was calibrated on (JSON-able): meshes, scenarios, samples,
        whether load scaling was used, the residual RMS.
    """

    features: str
    scale: float
    w_obs: FloatArray
    w_grid: FloatArray
    cov_unit: FloatArray
    a_inv: FloatArray
    floor: float
    leverage_max: float
    cost: float
    info: dict[str, Any] = field(default_factory=dict, hash=False)
    w_targets: FloatArray = field(default_factory=lambda: np.zeros((1, 0)))
    cov_grid: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    cov_targets: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 3)))

    def mean(self, z: FloatArray) -> FloatArray:
        """mu(z) (m,): the mean marker discrepancy at coarse observation z."""
        return np.asarray(feature_matrix(z, self.scale, self.features)[0] @ self.w_obs)

    def mean_grid(self, z: FloatArray) -> FloatArray:
        """The mean grid discrepancy (G d,) at coarse observation z."""
        return np.asarray(feature_matrix(z, self.scale, self.features)[0] @ self.w_grid)

    def mean_targets(self, z: FloatArray) -> FloatArray:
        """The mean targets' discrepancy (3 T,) at coarse observation z."""
        phi = feature_matrix(z, self.scale, self.features)[0]
        return np.asarray(phi @ self.w_targets)

    def jacobian(self, z: FloatArray) -> FloatArray:
        """The Jacobian d mu / d z (m, m) at z."""
        z = np.asarray(z, dtype=float)
        jphi = _feature_jacobian(z, self.scale, self.features)
        return np.asarray(self.w_obs.T @ jphi)

    def leverage(self, z: FloatArray) -> float:
        """h(z) = phi(z)^T A^-1 phi(z): how far z is from the samples."""
        phi = feature_matrix(z, self.scale, self.features)[0]
        return float(phi @ self.a_inv @ phi)

    def spread(self, z: FloatArray) -> float:
        """t(z) + t_0 + h(z): the factor of every residual covariance at z."""
        t = float(np.sum(np.square(z))) / self.scale**2
        return t + self.floor + self.leverage(z)

    def cov(self, z: FloatArray) -> FloatArray:
        """Sigma(z) = C (|z|^2 / z_s^2 + t_0 + h(z)) (m, m)."""
        return np.asarray(self.cov_unit * self.spread(z))

    def grid_cov(self, z: FloatArray) -> FloatArray:
        """The grid discrepancy's covariance per point (G, d, d) at z."""
        return np.asarray(self.cov_grid * self.spread(z))

    def targets_cov(self, z: FloatArray) -> FloatArray:
        """The targets' discrepancy covariance per target (T, 3, 3) at z."""
        return np.asarray(self.cov_targets * self.spread(z))

    def extrapolates(self, z: FloatArray) -> bool:
        """Whether z lies beyond the calibrated load states (leverage above all)."""
        return self.leverage(z) > self.leverage_max * (1 + 1e-9)

    # --- storage ----------------------------------------------------------

    def arrays(self) -> dict[str, FloatArray]:
        """The numeric content, by name (what is stored and digested)."""
        return {
            "w_obs": self.w_obs,
            "w_grid": self.w_grid,
            "cov_unit": self.cov_unit,
            "a_inv": self.a_inv,
            "w_targets": self.w_targets,
            "cov_grid": self.cov_grid,
            "cov_targets": self.cov_targets,
            "scalars": np.array(
                [self.scale, self.floor, self.leverage_max, self.cost]
            ),
        }

    def save(self, path: Path, key: str) -> None:
        """Write to ``path`` (``.npz``, no pickle) atomically, with a digest."""
        arrays = self.arrays()
        meta = json.dumps({"features": self.features, "info": self.info})
        check = digest(np.concatenate([a.ravel() for a in arrays.values()]))
        content = {"meta": np.array(meta), "digest": np.array(check), **arrays}
        write_entry(path, key, content, "discrepancy")

    @classmethod
    def load(cls, path: Path, key: str) -> Discrepancy | None:
        """The entry at ``path`` if its key and content digest match, else None."""
        names = ("w_obs", "w_grid", "cov_unit", "a_inv", "w_targets", "cov_grid",
                 "cov_targets", "scalars")  # fmt: skip

        def check(data: dict[str, Any]) -> None:
            arrays = [np.asarray(data[n], dtype=float).ravel() for n in names]
            if str(data["digest"]) != digest(np.concatenate(arrays)):
                raise ValueError("content digest mismatch (altered or damaged)")
            meta = json.loads(str(data["meta"]))
            if not isinstance(meta.get("features"), str) or "info" not in meta:
                raise ValueError("meta without features or info")

        data = read_entry(path, key, check, "discrepancy")
        if data is None:
            return None
        arrays = {n: np.array(data[n], dtype=float) for n in names}
        meta = json.loads(str(data["meta"]))
        scale, floor, lev, cost = arrays.pop("scalars")
        return cls(features=meta["features"], scale=float(scale), floor=float(floor),
                   leverage_max=float(lev), cost=float(cost), info=meta["info"],
                   **arrays)  # fmt: skip
