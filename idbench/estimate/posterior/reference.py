"""The reference posterior of a run: the method its settings choose."""

from __future__ import annotations

from collections.abc import Sequence

from idbench.core.interfaces import ForwardModel, Observation, Prior
from idbench.estimate.posterior.grid import grid_posterior
from idbench.estimate.posterior.mcmc import mcmc_posterior
from idbench.estimate.posterior.result import Posterior
from idbench.estimate.posterior.settings import PosteriorSettings


def reference_posterior(
    model: ForwardModel,
    prior: Prior,
    observations: Sequence[Observation | None],
    settings: PosteriorSettings | None = None,
) -> Posterior:
    """The posterior of the model's parameters given a run's observations.

    Parameters
    ----------
    model
        The (coarse) forward model the estimators use.
    prior
        The run's prior in natural units.
    observations
        The run's stream: entry k-1 is step k's observation or None.
    settings
        Method, grid, budget; default :class:`PosteriorSettings`.

    Returns
    -------
    Posterior
        Grid quadrature for p = 1, MCMC for p >= 2 (``method = "auto"``).
    """
    settings = settings or PosteriorSettings()
    if settings.method_for(model.parameters.p) == "grid":
        return grid_posterior(model, prior, observations, settings)
    return mcmc_posterior(model, prior, observations, settings)
