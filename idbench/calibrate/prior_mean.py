r"""The mean approximation error at the prior mean: an offset per frame.

The lightest form of the approximation error approach (Kaipio and Somersalo
2007): a coarse model's prediction h_c differs from a finer model's h_f of
the same body by a discrepancy that, for a stiffness field, depends far more
on the load state than on the field itself. Its value at the prior mean
theta_0, frame by frame,

.. math::

    \mu_k = h_{f,k}(u_f(\theta_0)) - h_{c,k}(u_c(\theta_0)), \qquad
    y_k = h_{c,k}(u_c(\theta)) + \mu_k + e_k,

costs one path on the finer mesh (at theta_0, never the truth's values) and
corrects what both the mesh's stiffness error (its locking) and its geometry
(a coarse surface's facets) do to each observed value, for any observation
model: a cloud's point distances, the tool's force, markers. The offsets do
not depend on theta, so the linearizations, the adjoint and every estimator
are unchanged (:class:`~idbench.observe.observed_model.ObservedModel` adds
them in ``observe``). What it leaves is the discrepancy's change from
theta_0 to theta, measured against the inclusion's own signal by the
stiffness-maps study.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idbench.core.interfaces import FloatArray


def path_observations(seen: Any, theta: FloatArray) -> list[FloatArray]:
    """``seen.observe`` at each step 1..K of the path at ``theta``."""
    x = np.asarray(seen.reset(), dtype=float)
    out = []
    for k in range(1, seen.n_steps + 1):
        x = np.asarray(seen.step(theta, k, x), dtype=float)
        out.append(np.asarray(seen.observe(x), dtype=float))
    return out


def prior_mean_offsets(fine: Any, coarse: Any, theta0: FloatArray) -> list[FloatArray]:
    """mu_k (m,) for each step k = 1..K: the finer minus the coarse prediction.

    ``fine`` and ``coarse`` are the two meshes' models seen through the same
    observation model and frames (their ``observe`` is step k's h); theta0
    (p,) in the models' parameters (the same cells on both meshes).
    """
    theta0 = np.asarray(theta0, dtype=float)
    return [
        f - c
        for f, c in zip(
            path_observations(fine, theta0), path_observations(coarse, theta0),
            strict=True,
        )
    ]  # fmt: skip
