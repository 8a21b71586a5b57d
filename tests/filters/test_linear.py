"""Exactness of the estimators on a linear-Gaussian toy model.

For u_k = (k/K) A theta and y_k = H u_k + e_k, e_k ~ N(0, s^2 I), the posterior
of theta given the prior N(m0, P0) and the observations up to step k is
Gaussian with P^-1 = P0^-1 + sum_j J_j^T J_j / s^2 and
mean = P (P0^-1 m0 + sum_j J_j^T y_j / s^2), J_j = (j/K) H A.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.helpers import linear_data, linear_posteriors
from support.toymodels import LinearToy, SensitiveLinearToy

from idbench import Prior
from idbench_filters import BatchLs, Rls, RoUkf, Ukf

SIGMA = 0.05
RTOL = 1e-8


def make_data(model: LinearToy, theta: np.ndarray, every: int, seed: int = 1):
    return linear_data(model, theta, every, SIGMA, seed)


def exact_posteriors(model: LinearToy, prior: Prior, obs: dict):
    """Sequential Gaussian posterior (mean, std) after each step, computed directly."""
    posteriors = linear_posteriors(model, prior, obs, SIGMA)
    return [(mean, np.sqrt(np.diag(P))) for mean, P in posteriors]


def least_squares_answer(model: LinearToy, obs: dict) -> np.ndarray:
    Js = np.vstack([model.jac(k) for k in obs])
    ys = np.concatenate([o.values for o in obs.values()])
    return np.linalg.lstsq(Js, ys, rcond=None)[0]


def run(est, model, prior, obs):
    est.start(model, prior)
    return [est.update(k, obs.get(k)) for k in range(1, model.n_steps + 1)]


CASES = [(1, 1), (2, 1), (2, 2)]  # (p, observe every)


@pytest.mark.parametrize(("p", "every"), CASES)
@pytest.mark.parametrize(
    "est",
    [
        RoUkf(transform="identity"),
        RoUkf(transform="identity", sigma_points="star"),
        Ukf(transform="identity"),
        Rls(transform="identity"),
    ],
    ids=["ro-ukf-simplex", "ro-ukf-star", "ukf", "rls"],
)
def test_filters_match_exact_posterior(est, p, every):
    model = SensitiveLinearToy(p=p, n=4, m=3, n_steps=6, seed=p)
    theta = np.array([3.0, -1.5][:p])
    prior = Prior((1.0, 0.5)[:p], (2.0, 1.5)[:p])
    obs = make_data(model, theta, every)
    estimates = run(est, model, prior, obs)
    for k, (e, (mean, std)) in enumerate(
        zip(estimates, exact_posteriors(model, prior, obs), strict=True), start=1
    ):
        np.testing.assert_allclose(e.mean, mean, rtol=RTOL, err_msg=f"step {k}")
        np.testing.assert_allclose(e.std, std, rtol=RTOL, err_msg=f"step {k}")


@pytest.mark.parametrize("p", [1, 2])
def test_rls_finite_differences_match_sensitivity(p):
    """Without ``sensitivity`` RLS falls back to finite differences (exact here)."""
    model = LinearToy(p=p, n=4, m=3, n_steps=6, seed=p)
    theta = np.array([3.0, -1.5][:p])
    prior = Prior((1.0, 0.5)[:p], (2.0, 1.5)[:p])
    obs = make_data(model, theta, 1)
    last = run(Rls(transform="identity"), model, prior, obs)[-1]
    mean, std = exact_posteriors(model, prior, obs)[-1]
    np.testing.assert_allclose(last.mean, mean, rtol=1e-6)
    np.testing.assert_allclose(last.std, std, rtol=1e-6)
    # one solve a step plus p finite-difference solves per observation
    assert last.cost.forward_solves == model.n_steps * (1 + p)


@pytest.mark.parametrize("sensitive", [True, False])
@pytest.mark.parametrize(("p", "every"), CASES)
def test_batch_ls_is_closed_form_least_squares(p, every, sensitive):
    cls = SensitiveLinearToy if sensitive else LinearToy
    model = cls(p=p, n=4, m=3, n_steps=6, seed=p)
    theta = np.array([3.0, -1.5][:p])
    prior = Prior((1.0, 0.5)[:p], (2.0, 1.5)[:p])
    obs = make_data(model, theta, every)
    estimates = run(BatchLs(transform="identity"), model, prior, obs)
    for e in estimates[:-1]:  # refit="end": the prior until step K
        np.testing.assert_array_equal(e.mean, prior.mean)
        assert e.state is None
    rtol = RTOL if sensitive else 1e-6
    np.testing.assert_allclose(
        estimates[-1].mean, least_squares_answer(model, obs), rtol=rtol
    )
    assert estimates[-1].state is not None


def test_batch_ls_refit_each_tracks_growing_data():
    model = SensitiveLinearToy(p=2, n=4, m=3, n_steps=6, seed=2)
    theta = np.array([3.0, -1.5])
    prior = Prior((1.0, 0.5), (2.0, 1.5))
    obs = make_data(model, theta, 2)
    estimates = run(BatchLs(transform="identity", refit="each"), model, prior, obs)
    for k, e in enumerate(estimates, start=1):
        if k >= 2:
            seen = {j: o for j, o in obs.items() if j <= k}
            np.testing.assert_allclose(
                e.mean, least_squares_answer(model, seen), rtol=RTOL
            )


@pytest.mark.parametrize("sigma_points", ["simplex", "star"])
def test_ro_ukf_innovation_is_the_kalman_innovation(sigma_points):
    # nu = y_k - J_k m_{k-1}, S = J_k P_{k-1} J_k^T + s^2 I (linear: exact)
    p = 2
    model = SensitiveLinearToy(p=p, n=4, m=3, n_steps=6, seed=p)
    prior = Prior((1.0, 0.5), (2.0, 1.5))
    obs = make_data(model, np.array([3.0, -1.5]), every=2)
    est = RoUkf(transform="identity", sigma_points=sigma_points)
    est.start(model, prior)
    assert est.innovation is None
    m, P = np.asarray(prior.mean, float), np.diag(np.asarray(prior.std) ** 2)
    for k in range(1, model.n_steps + 1):
        est.update(k, obs.get(k))
        if k not in obs:
            continue
        J = model.jac(k)
        nu = obs[k].values - J @ m
        S = J @ P @ J.T + SIGMA**2 * np.eye(3)
        np.testing.assert_allclose(est.innovation[0], nu, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(est.innovation[1], S, rtol=1e-8, atol=1e-12)
        gain = P @ J.T @ np.linalg.inv(S)
        m, P = m + gain @ nu, P - gain @ J @ P
