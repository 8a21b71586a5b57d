"""Ensemble filters (EnKF, ETKF): exactness on the linear-Gaussian toy model,
settings, seeding, the batched model step, and recovery of E_true on the beam.

Linear toy: u_k = (k/K) A theta, y_k = H u_k + e_k, e_k ~ N(0, s^2 I); the
posterior after step k is Gaussian with P^-1 = P0^-1 + sum_j J_j^T J_j / s^2,
mean = P (P0^-1 m0 + sum_j J_j^T y_j / s^2), J_j = (j/K) H A.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.beam_runs import E_TRUE, beam, observe_truth
from support.helpers import SIGMA, linear_posteriors, make_data
from support.toymodels import BatchedToy, LinearToy

from idbench import Diverged, ModelFailure, Prior
from idbench.registry.testing import check_estimator
from idbench_filters import Enkf, Etkf

CASES = [(1, 1), (2, 1), (2, 2)]  # (p, observe every)


def kalman(model: LinearToy, prior: Prior, obs: dict):
    """Exact posterior (mean, covariance) of theta after each step."""
    return linear_posteriors(model, prior, obs, SIGMA)


def run(est, model, prior, obs):
    est.start(model, prior)
    return [est.update(k, obs.get(k)) for k in range(1, model.n_steps + 1)]


def toy_case(p: int, every: int):
    model = LinearToy(p=p, n=4, m=3, n_steps=6, seed=p)
    theta = np.array([3.0, -1.5][:p])
    prior = Prior((1.0, 0.5)[:p], (2.0, 1.5)[:p])
    return model, prior, make_data(model, theta, every)


def ensemble_cov(est) -> np.ndarray:
    xi = est.ensemble[:, -est._run.model.parameters.p :]
    return np.atleast_2d(np.cov(xi, rowvar=False))


# --- exactness on the linear-Gaussian model ----------------------------------


@pytest.mark.parametrize(("p", "every"), CASES)
@pytest.mark.parametrize("members", [None, 3, 7])
def test_etkf_is_the_kalman_filter(p, every, members):
    """Exact initial moments + linear model: ETKF = KF to round-off (N >= p + 1)."""
    model, prior, obs = toy_case(p, every)
    est = Etkf(transform="identity", members=members)
    trace = run(est, model, prior, obs)
    for k, (e, (mean, P)) in enumerate(
        zip(trace, kalman(model, prior, obs), strict=True), start=1
    ):
        np.testing.assert_allclose(e.mean, mean, rtol=1e-9, err_msg=f"step {k}")
        np.testing.assert_allclose(
            e.std, np.sqrt(np.diag(P)), rtol=1e-9, err_msg=f"step {k}"
        )
    np.testing.assert_allclose(ensemble_cov(est), P, rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize(("p", "every"), CASES)
@pytest.mark.parametrize("seed", [0, 1])
def test_enkf_converges_to_the_kalman_filter(p, every, seed):
    """Large N: mean and covariance within a few Monte-Carlo standard errors."""
    n = 4000
    model, prior, obs = toy_case(p, every)
    est = Enkf(transform="identity", members=n, seed=seed)
    trace = run(est, model, prior, obs)
    for k, (e, (mean, P)) in enumerate(
        zip(trace, kalman(model, prior, obs), strict=True), start=1
    ):
        std = np.sqrt(np.diag(P))
        # standard error of an ensemble mean ~ std / sqrt(N), of a std ~ std /
        # sqrt(2N); allow 4 of them
        assert np.all(np.abs(e.mean - mean) < 4 * std / np.sqrt(n)), f"step {k}"
        assert np.all(np.abs(e.std / std - 1) < 4 / np.sqrt(2 * n)), f"step {k}"
    corr = P / np.outer(std, std)
    c = ensemble_cov(est)
    est_corr = c / np.outer(np.sqrt(np.diag(c)), np.sqrt(np.diag(c)))
    np.testing.assert_allclose(est_corr, corr, atol=4 / np.sqrt(n))


def test_without_observations_the_prior_is_kept():
    model, prior, _ = toy_case(2, 1)
    for est in (Etkf(transform="identity"), Enkf(transform="identity")):
        trace = run(est, model, prior, {})
        np.testing.assert_allclose(trace[-1].mean, prior.mean, rtol=1e-12)
        np.testing.assert_allclose(trace[-1].std, prior.std, rtol=1e-12)


def test_log_transform_reports_median_and_log_std():
    """E = exp(mean xi), E_std = E std(xi); the prior is the log-normal one."""
    model, _, _ = toy_case(1, 1)
    model.parameters = type(model.parameters)(("E",), (1e-3,), (1e6,))
    prior = Prior((2500.0,), (2500.0,))
    est = Etkf(members=50)
    e = run(est, model, prior, {})[-1]
    s_xi = np.sqrt(np.log(2.0))
    np.testing.assert_allclose(e.mean, [2500.0], rtol=1e-12)
    np.testing.assert_allclose(e.std, [2500.0 * s_xi], rtol=1e-12)


# --- settings, seeds, cost ----------------------------------------------------


@pytest.mark.parametrize("cls", [Enkf, Etkf])
@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"members": 1}, "members = 1"),
        ({"members": 0}, "members = 0"),
        ({"members": 2.5}, "members = 2.5"),
        ({"members": True}, "members = True"),
        ({"inflation": 0.9}, "inflation = 0.9"),
        ({"inflation": float("nan")}, "inflation = nan"),
        ({"init": "sobol"}, "init = 'sobol'"),
        ({"seed": -1}, "seed = -1"),
        ({"transform": "logit"}, "transform = 'logit'"),
    ],
)
def test_bad_settings_raise_naming_the_value(cls, settings, match):
    with pytest.raises(ValueError, match=match):
        cls(**settings)


def test_exact_init_needs_more_members_than_parameters():
    model, prior, _ = toy_case(2, 1)
    with pytest.raises(ValueError, match="members = 2 is too few"):
        Etkf(transform="identity", members=2).start(model, prior)
    # plain draws work with 2 members
    Etkf(transform="identity", members=2, init="random").start(model, prior)


@pytest.mark.parametrize("cls", [Enkf, Etkf])
def test_protocol_conformance(cls):
    model, prior, _ = toy_case(2, 1)
    check_estimator(cls, model, prior, transform="identity")


@pytest.mark.parametrize("cls", [Enkf, Etkf])
def test_same_seed_same_result_other_seed_other_result(cls):
    model, prior, obs = toy_case(2, 1)
    a = run(cls(transform="identity", seed=5), model, prior, obs)[-1]
    b = run(cls(transform="identity", seed=5), model, prior, obs)[-1]
    c = run(cls(transform="identity", seed=6), model, prior, obs)[-1]
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.std, b.std)
    if cls is Enkf:  # the perturbations differ (ETKF: exact for any seed here)
        assert not np.array_equal(a.mean, c.mean)
        assert not np.array_equal(a.std, c.std)


@pytest.mark.parametrize("cls", [Enkf, Etkf])
def test_cost_is_members_solves_a_step(cls):
    model, prior, obs = toy_case(2, 2)
    est = cls(transform="identity", members=5)
    trace = run(est, model, prior, obs)
    assert [e.cost.forward_solves for e in trace] == [5 * k for k in range(1, 7)]
    assert est.solves_per_step == 5
    # default size 2p + 2
    est = cls(transform="identity")
    est.start(model, prior)
    assert est.solves_per_step == 6


def test_inflation_widens_the_spread():
    model, prior, obs = toy_case(1, 1)
    plain = run(Etkf(transform="identity"), model, prior, obs)[-1]
    wide = run(Etkf(transform="identity", inflation=1.1), model, prior, obs)[-1]
    assert wide.std[0] > 1.2 * plain.std[0]


@pytest.mark.parametrize("cls", [Enkf, Etkf])
def test_innovation_is_kept_for_nis(cls):
    model, prior, obs = toy_case(1, 2)
    est = cls(transform="identity", members=2000)
    est.start(model, prior)
    est.update(1, None)
    assert est.innovation is None
    mean, P = kalman(model, prior, obs)[0]  # state after step 1 = prior
    est.update(2, obs[2])
    nu, S = est.innovation
    J = model.jac(2)
    np.testing.assert_allclose(nu, obs[2].values - J @ mean, rtol=1e-9)
    if cls is Etkf:  # exact moments: S = J P J^T + R exactly
        np.testing.assert_allclose(S, J @ P @ J.T + SIGMA**2 * np.eye(3), rtol=1e-9)


# --- the batched model step ----------------------------------------------------


class RaisingBatchToy(BatchedToy):
    def step_many(self, thetas, k, states):
        self.batched += 1
        raise ModelFailure("batched Newton failed", step=k)


@pytest.mark.parametrize("cls", [Enkf, Etkf])
def test_uses_step_many_and_matches_the_loop(cls):
    plain, prior, obs = toy_case(2, 1)
    batched = BatchedToy(p=2, n=4, m=3, n_steps=6, seed=2)
    a = run(cls(transform="identity"), plain, prior, obs)[-1]
    b = run(cls(transform="identity"), batched, prior, obs)[-1]
    assert batched.batched == 6
    np.testing.assert_allclose(b.mean, a.mean, rtol=1e-12)
    np.testing.assert_allclose(b.std, a.std, rtol=1e-12)
    assert b.cost.forward_solves == a.cost.forward_solves


def test_step_many_failures_fall_back_to_single_steps():
    _, prior, obs = toy_case(2, 1)
    ref = run(Etkf(transform="identity"), toy_case(2, 1)[0], prior, obs)[-1]
    nan_rows = BatchedToy(p=2, n=4, m=3, n_steps=6, seed=2, fail_rows=(1,))
    e = run(Etkf(transform="identity"), nan_rows, prior, obs)[-1]
    np.testing.assert_allclose(e.mean, ref.mean, rtol=1e-12)
    raising = RaisingBatchToy(p=2, n=4, m=3, n_steps=6, seed=2)
    e = run(Etkf(transform="identity"), raising, prior, obs)[-1]
    np.testing.assert_allclose(e.mean, ref.mean, rtol=1e-12)
    assert raising.batched == 6


def test_a_member_that_cannot_be_solved_diverges():
    from support.toymodels import FailingToy

    model = FailingToy(fail_at=3, mode="raise")
    prior = Prior((2.0,), (0.5,))
    est = Enkf()
    est.start(model, prior)
    for k in (1, 2):
        est.update(k, None)
    with pytest.raises(Diverged, match="step 3"):
        est.update(3, None)


# --- the beam, mesh = truth -----------------------------------------------------


@pytest.fixture(scope="module")
def small_beam():
    model = beam("9x2x2")
    return model, observe_truth(model, [E_TRUE])


@pytest.mark.parametrize(
    "est",
    [Etkf(), Enkf(), Etkf(inflation=1.05), Enkf(members=8, seed=1)],
    ids=repr,
)
@pytest.mark.parametrize("prior_mean", [2500.0, 10000.0])
def test_recovers_e_true_on_the_beam(small_beam, est, prior_mean):
    model, obs = small_beam
    trace = run(est, model, Prior((prior_mean,), (prior_mean,)), obs)
    assert abs(trace[-1].mean[0] / E_TRUE - 1) < 0.001
    assert 0 < trace[-1].std[0] < 1.0  # noise-free data: a tight posterior
    n = est.members or 4
    assert trace[-1].cost.forward_solves == n * model.n_steps
