"""Reference posterior: grid quadrature (p = 1) and MCMC (p >= 2).

Exact answers: the linear toy u_k = (k/K) A theta with the identity transform
(Gaussian prior x Gaussian likelihood), and a log-linear toy u_k = (k/K) A
ln(theta) with the log transform (xi Gaussian, theta log-normal).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, stats
from support.beam_runs import E_TRUE, beam
from support.helpers import SIGMA, make_data
from support.toymodels import BatchedToy, LinearToy

from idbench import Observation, Prior
from idbench.estimate.posterior import (
    LEVELS,
    PosteriorSettings,
    grid_posterior,
    mcmc_posterior,
    reference_posterior,
)

IDENTITY = PosteriorSettings(transform="identity")


def toy(p: int, cls=LinearToy, sigma=SIGMA, **kw):
    model = cls(p=p, n=4, m=3, n_steps=6, seed=p, **kw)
    theta = np.array([3.0, -1.5][:p])
    prior = Prior((1.0, 0.5)[:p], (2.0, 1.5)[:p])
    obs = make_data(model, theta, 1)
    if sigma != SIGMA:
        rng = np.random.default_rng(2)
        obs = {
            k: Observation(model.jac(k) @ theta + sigma * rng.normal(size=3), sigma, k)
            for k in obs
        }
    stream = [obs.get(k) for k in range(1, model.n_steps + 1)]
    return model, prior, obs, stream


def exact(model, prior, obs, sigma=SIGMA):
    info = np.diag(1.0 / np.asarray(prior.std) ** 2)
    rhs = info @ np.asarray(prior.mean)
    for k, o in obs.items():
        J = model.jac(k)
        info = info + J.T @ J / sigma**2
        rhs = rhs + J.T @ o.values / sigma**2
    P = np.linalg.inv(info)
    return P @ rhs, P


class LogLinearToy(LinearToy):
    """u_k = (k/K) A ln(theta): linear in xi = ln(theta)."""

    def __init__(self, **kw):
        super().__init__(lower=1e-6, upper=1e6, **kw)

    def step(self, theta, k, state, *, substeps=1):
        return super().step(np.log(np.asarray(theta, dtype=float)), k, state)


# --- p = 1: grid quadrature ----------------------------------------------------


@pytest.mark.parametrize("sigma", [SIGMA, 1e-7])
def test_grid_is_the_exact_gaussian_posterior(sigma):
    """Also when the posterior is 1e-8 of the prior's width (the zoom finds it)."""
    model, prior, obs, stream = toy(1, sigma=sigma)
    mean, P = exact(model, prior, obs, sigma)
    sd = np.sqrt(P[0, 0])
    settings = PosteriorSettings(transform="identity", sigma_floor=1e-9)
    post = grid_posterior(model, prior, stream, settings)
    assert post.method == "grid" and post.converged
    np.testing.assert_allclose(post.mean, mean, rtol=0, atol=1e-4 * sd)
    np.testing.assert_allclose(post.std, [sd], rtol=1e-6)
    want = stats.norm(mean[0], sd).ppf(LEVELS)
    np.testing.assert_allclose(post.quantiles[:, 0], want, rtol=0, atol=1e-3 * sd)
    np.testing.assert_allclose(post.quantile(0.5), mean, rtol=0, atol=1e-3 * sd)
    assert abs(post.map[0] - mean[0]) < 1e-3 * sd
    assert integrate.trapezoid(post.density, post.grid) == pytest.approx(1.0)
    want_density = stats.norm(mean[0], sd).pdf(post.grid)
    np.testing.assert_allclose(
        post.density, want_density, atol=1e-6 * want_density.max()
    )
    searches = post.diagnostics["zooms"] + 1
    assert post.n_solves == 6 * (41 * searches + 201)  # every path to step 6


def test_grid_applies_the_sigma_floor():
    """R = max(sigma, floor)^2: a 1e-7 noise counts as the 1e-6 default floor."""
    model, prior, obs, stream = toy(1, sigma=1e-7)
    _, P = exact(model, prior, obs, 1e-6)
    post = grid_posterior(model, prior, stream, IDENTITY)
    np.testing.assert_allclose(post.std, [np.sqrt(P[0, 0])], rtol=1e-5)


def test_grid_log_transform_is_the_log_normal_posterior():
    """Prior log-normal as the filters', model linear in xi: theta | y log-normal."""
    model, _, _, _ = toy(1, cls=LogLinearToy)
    prior = Prior((20.0,), (15.0,))
    xi_true = np.log([25.0])
    rng = np.random.default_rng(4)
    obs = {
        k: Observation(model.jac(k) @ xi_true + SIGMA * rng.normal(size=3), SIGMA, k)
        for k in range(1, 7)
    }
    # the same prior in xi: mean ln 20, variance ln(1 + 15^2/20^2)
    xi_prior = Prior((np.log(20.0),), (np.sqrt(np.log1p(15.0**2 / 20.0**2)),))
    m, P = exact(model, xi_prior, obs)
    s = np.sqrt(P[0, 0])
    want = stats.lognorm(s=s, scale=np.exp(m[0]))
    post = grid_posterior(model, prior, [obs[k] for k in range(1, 7)])
    np.testing.assert_allclose(post.mean, [want.mean()], rtol=1e-7)
    np.testing.assert_allclose(post.std, [want.std()], rtol=1e-6)
    np.testing.assert_allclose(
        post.quantiles[:, 0], want.ppf(LEVELS), rtol=0, atol=2e-3 * want.std()
    )
    # the mode of the theta density: exp(m - s^2)
    assert post.map[0] == pytest.approx(np.exp(m[0] - s**2), rel=1e-5)
    assert integrate.trapezoid(post.density, post.grid) == pytest.approx(1.0)
    assert np.all(
        np.diff(np.log(post.grid)) == pytest.approx(np.log(post.grid[1] / post.grid[0]))
    )


def test_grid_uses_step_many_and_counts_the_budget():
    model, prior, _, stream = toy(1)
    batched = BatchedToy(p=1, n=4, m=3, n_steps=6, seed=1)
    a = grid_posterior(model, prior, stream, IDENTITY)
    b = grid_posterior(batched, prior, stream, IDENTITY)
    assert batched.batched > 0
    np.testing.assert_allclose(b.mean, a.mean, rtol=1e-12)
    assert b.n_solves == a.n_solves  # every path simulated to the last observation


def test_grid_stops_at_the_last_observed_step():
    model, prior, obs, stream = toy(1)
    short = [*stream[:3], None, None, None]
    post = grid_posterior(model, prior, short, IDENTITY)
    assert post.n_solves == 3 * (41 * (post.diagnostics["zooms"] + 1) + 201)
    mean, _ = exact(model, prior, {k: obs[k] for k in (1, 2, 3)})
    np.testing.assert_allclose(post.mean, mean, rtol=1e-8)


def test_grid_cut_off_by_its_search_range_is_not_converged():
    """A posterior 40 prior sds away from the prior mean lies outside span = 3."""
    model, _, _, stream = toy(1)
    tight = Prior((1.0,), (0.05,))  # theta_true = 3 is 40 sds away
    post = grid_posterior(
        model,
        tight,
        stream,
        PosteriorSettings(transform="identity", span=3.0, tail=25.0),
    )
    wide = grid_posterior(
        model, tight, stream, PosteriorSettings(transform="identity", span=60.0)
    )
    assert wide.converged
    assert not post.converged


def test_grid_truncated_at_a_model_bound_is_converged():
    """The model's bounds truncate the density; that is the answer, not a cut."""
    model, prior, obs, stream = toy(1, lower=2.99, upper=1e6)
    mean, P = exact(model, prior, obs)
    sd = np.sqrt(P[0, 0])
    post = grid_posterior(model, prior, stream, IDENTITY)
    assert post.converged
    assert post.grid[0] > 2.99 and post.grid[0] < 2.99 + 0.1 * sd
    want = stats.truncnorm((2.99 - mean[0]) / sd, np.inf, loc=mean[0], scale=sd)
    np.testing.assert_allclose(post.mean, [want.mean()], rtol=0, atol=1e-3 * sd)
    np.testing.assert_allclose(post.std, [want.std()], rtol=1e-3)


# --- p >= 2 (and p = 1): MCMC ------------------------------------------------------


@pytest.mark.parametrize("p", [1, 2])
def test_mcmc_matches_the_exact_posterior(p):
    model, prior, obs, stream = toy(p)
    mean, P = exact(model, prior, obs)
    sd = np.sqrt(np.diag(P))
    post = mcmc_posterior(model, prior, stream, IDENTITY)
    assert post.method == "mcmc" and post.converged
    se = sd / np.sqrt(post.diagnostics["ess_min"])
    assert np.all(np.abs(post.mean - mean) < 4 * se)
    # std of a std estimate ~ sd / sqrt(2 ESS)
    assert np.all(
        np.abs(post.std / sd - 1) < 4 / np.sqrt(2 * post.diagnostics["ess_min"])
    )
    np.testing.assert_allclose(post.map, mean, rtol=1e-5)
    assert post.samples.shape == (4 * 1000, p)
    if p == 2:
        corr = np.corrcoef(post.samples.T)[0, 1]
        assert abs(corr - P[0, 1] / (sd[0] * sd[1])) < 0.1
    assert reference_posterior(model, prior, stream, IDENTITY).method == (
        "grid" if p == 1 else "mcmc"
    )


def test_mcmc_is_seeded():
    model, prior, _, stream = toy(2)
    s = PosteriorSettings(transform="identity", warmup=100, samples=200)
    a = mcmc_posterior(model, prior, stream, s)
    b = mcmc_posterior(model, prior, stream, s)
    c = mcmc_posterior(
        model,
        prior,
        stream,
        PosteriorSettings(transform="identity", warmup=100, samples=200, seed=1),
    )
    np.testing.assert_array_equal(a.samples, b.samples)
    assert not np.array_equal(a.samples, c.samples)


def test_short_mcmc_is_marked_not_converged():
    model, prior, _, stream = toy(2)
    post = mcmc_posterior(
        model,
        prior,
        stream,
        PosteriorSettings(transform="identity", chains=2, warmup=0, samples=20),
    )
    assert not post.converged
    assert post.diagnostics["tau_max"] * 50 > 20


# --- bad input ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"points": 5}, "points = 5"),
        ({"zoom_points": 3}, "zoom_points = 3"),
        ({"max_solves": 0}, "max_solves = 0"),
        ({"chains": 1}, "chains = 1"),
        ({"samples": 2.5}, "samples = 2.5"),
        ({"rhat_max": 1.0}, "rhat_max = 1.0"),
        ({"span": -1.0}, "span = -1.0"),
        ({"method": "nuts"}, "method = 'nuts'"),
        ({"transform": "logit"}, "transform = 'logit'"),
    ],
)
def test_bad_settings_raise_naming_the_value(settings, match):
    with pytest.raises(ValueError, match=match):
        PosteriorSettings(**settings)


def test_budgets_that_cannot_be_met():
    model, prior, _, stream = toy(1)
    with pytest.raises(ValueError, match="max_solves = 500 cannot hold"):
        grid_posterior(model, prior, stream, PosteriorSettings(max_solves=500))
    model2, prior2, _, stream2 = toy(2)
    with pytest.raises(ValueError, match="max_solves = 10000 cannot hold 4 chains"):
        mcmc_posterior(model2, prior2, stream2, PosteriorSettings(max_solves=10_000))
    with pytest.raises(ValueError, match="needs p = 1"):
        grid_posterior(model2, prior2, stream2)
    with pytest.raises(ValueError, match="no observations"):
        grid_posterior(model, prior, [None] * 6)


# --- the beam, mesh = truth ---------------------------------------------------------


def test_beam_posterior_mean_is_near_e_true():
    model = beam("9x2x2", n_steps=6)
    rng = np.random.default_rng(0)
    u, stream = model.reset(), []
    for k in range(1, 7):
        u = model.step(np.array([E_TRUE]), k, u)
        y = model.observe(u) + 1e-4 * rng.standard_normal(6)
        stream.append(Observation(y, 1e-4, k))
    s = PosteriorSettings(points=61, zoom_points=21, span=3.0)
    post = reference_posterior(model, Prior((2500.0,), (2500.0,)), stream, s)
    assert post.converged and post.method == "grid"
    assert 0 < post.std[0] < 100
    assert abs(post.mean[0] - E_TRUE) < 4 * post.std[0]
    lo, hi = post.quantile(0.025)[0], post.quantile(0.975)[0]
    assert lo < post.mean[0] < hi


def test_occluded_values_are_left_out_of_the_likelihood():
    """NaN entries: the posterior of the visible ones (grid p = 1, MCMC's MAP p = 2)."""
    hidden = {2: [0], 3: [0, 1, 2], 5: [1, 2]}  # step 3: all NaN, no observation
    for p in (1, 2):
        model, prior, obs, _ = toy(p)
        info = np.diag(1.0 / np.asarray(prior.std) ** 2)
        rhs = info @ np.asarray(prior.mean)
        stream = []
        for k in range(1, model.n_steps + 1):
            y = np.array(obs[k].values, dtype=float)
            y[hidden.get(k, [])] = np.nan
            stream.append(Observation(y, SIGMA, k))
            seen = ~np.isnan(y)
            J = model.jac(k)[seen]
            info = info + J.T @ J / SIGMA**2
            rhs = rhs + J.T @ y[seen] / SIGMA**2
        P = np.linalg.inv(info)
        mean = P @ rhs
        if p == 1:
            post = grid_posterior(model, prior, stream, IDENTITY)
            sd = np.sqrt(P[0, 0])
            np.testing.assert_allclose(post.mean, mean, rtol=0, atol=1e-4 * sd)
            np.testing.assert_allclose(post.std, [sd], rtol=1e-6)
        else:
            post = mcmc_posterior(model, prior, stream, IDENTITY)
            np.testing.assert_allclose(post.map, mean, rtol=1e-5)
        assert np.all(np.isfinite(post.mean))
