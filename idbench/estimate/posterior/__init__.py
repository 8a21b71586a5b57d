r"""Reference posterior of a run's parameters given its data and its model.

What an ideal Bayesian would conclude with this (coarse) model from this data:
the filters' prior times the Gaussian likelihood of the whole observation
stream, each evaluation one simulation of the load path through the
:class:`~idbench.ForwardModel` protocol (``reset``, ``step``, ``observe``).

Prior and noise are the filters' (docs/design.md, section 4): with the ``"log"``
transform xi = ln theta ~ N(mu, Sigma) with mu_j = ln m_j and
Sigma_jj = ln(1 + s_j^2 / m_j^2) (the log-normal of mean m and std s), with
``"identity"`` theta ~ N(m, diag(s^2)) (:mod:`idbench.estimate.transforms`);
R_k = max(sigma_k, floor)^2 I. Then

.. math::

    \log \pi(\xi \mid y) = \text{const} - \tfrac12 (\xi - \mu)^T \Sigma^{-1}
    (\xi - \mu) - \sum_{k \text{ observed}}
    \frac{\lVert y_k - h(u_k(\theta(\xi))) \rVert^2}{2 r_k},

truncated to the model's parameter bounds (outside them, or where the model
cannot be solved even in sub-steps, the density is 0).

One module per concept:

- ``settings``: :class:`PosteriorSettings` and the budget checks
  (:func:`minimum_solves`, :func:`check_budget`);
- ``result``: :class:`Posterior` and the quantile :data:`LEVELS`;
- ``target``: :class:`~idbench.estimate.posterior.target.LogPosterior`, the density
  both methods explore (one path simulation per point), and
  :func:`model_error`;
- ``grid``: :func:`grid_posterior` (p = 1), quadrature on a zooming grid;
- ``mcmc``: :func:`mcmc_posterior` (any p), MAP and Laplace start, adaptive
  random-walk Metropolis;
- ``diagnostics``: split R-hat and the integrated autocorrelation time (emcee's);
- ``reference``: :func:`reference_posterior`, the method the settings choose.

The budget ``max_solves`` counts path simulations times steps simulated
(sub-step retries come on top); a budget that cannot hold the requested grid
or chains raises ValueError up front. When the model has
``step_many(thetas, k, states)`` all the paths of one batch (a grid, the
chains' proposals) advance together.
"""

from __future__ import annotations

from idbench.estimate.posterior.grid import grid_posterior
from idbench.estimate.posterior.mcmc import mcmc_posterior
from idbench.estimate.posterior.reference import reference_posterior
from idbench.estimate.posterior.result import LEVELS, Posterior
from idbench.estimate.posterior.settings import (
    METHODS,
    TRANSFORMS,
    PosteriorSettings,
    check_budget,
    minimum_solves,
)
from idbench.estimate.posterior.target import RETRY_SUBSTEPS, model_error

__all__ = [
    "LEVELS",
    "METHODS",
    "RETRY_SUBSTEPS",
    "TRANSFORMS",
    "Posterior",
    "PosteriorSettings",
    "check_budget",
    "grid_posterior",
    "mcmc_posterior",
    "minimum_solves",
    "model_error",
    "reference_posterior",
]
