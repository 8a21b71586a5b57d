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

The approximation-error correction of a run observed otherwise than by
markers (a cloud, a force, markers + cloud) takes that change into account
on the run's own frames (:func:`linear_offsets`): the discrepancy at theta_0
and at theta_0 moved one prior std s_j up and down in each ln theta_j (2p +
1 paths on each mesh) gives its slope (central differences) and what the
line leaves at those points (half the second difference, c_j),

.. math::

    G_{k,j} = \frac{\delta_k^+ - \delta_k^-}{2 s_j}, \qquad
    c_{k,j} = \frac{\delta_k^+ + \delta_k^- - 2\delta_k^0}{2}, \qquad
    \Sigma_k = \sum_j c_{k,j} c_{k,j}^T,

so y_k = h_c + mu_k + G_k (ln theta - xi_0) + e_k, e_k ~ N(0, R + Sigma_k)
(:class:`~idbench.observe.offsets.Offsets`; the seen model carries theta to
add the slope).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idbench.core.interfaces import FloatArray
from idbench.observe.offsets import Offsets


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


def linear_offsets(
    fine: Any, coarse: Any, theta0: FloatArray, std_xi: FloatArray
) -> Offsets:
    """mu_k, G_k and Sigma_k per step: the discrepancy over the prior (module doc).

    ``std_xi`` (p,): the prior's std of each ln theta_j.
    """
    theta0 = np.asarray(theta0, dtype=float)
    mu = np.stack(prior_mean_offsets(fine, coarse, theta0))  # (K, m)
    slopes, left = [], []
    for j, s in enumerate(np.asarray(std_xi, dtype=float)):
        up, down = theta0.copy(), theta0.copy()
        up[j] *= np.exp(s)
        down[j] *= np.exp(-s)
        d_up = np.stack(prior_mean_offsets(fine, coarse, up))
        d_down = np.stack(prior_mean_offsets(fine, coarse, down))
        slopes.append((d_up - d_down) / (2.0 * s))
        left.append((d_up + d_down - 2.0 * mu) / 2.0)
    G = np.stack(slopes, axis=2)  # (K, m, p)
    C = np.stack(left, axis=2)
    covs = np.einsum("kip,kjp->kij", C, C)
    return Offsets(list(mu), list(G), np.log(theta0), list(covs))
