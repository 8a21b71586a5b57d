"""Estimators on the scikit-fem beam: no discretisation gap, no noise.

The observations come from the model itself with E_true, so every estimator
must recover E_true from a wrong prior. Skipped while no ``svk-beam`` model is
registered.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.beam_runs import E_TRUE, beam, observe_truth

from idbench import Prior, Skipped
from idbench_filters import BatchLs, Lms, Rls, RoUkf, Ukf


def run(est, model, prior, obs):
    est.start(model, prior)
    return [est.update(k, obs.get(k)) for k in range(1, model.n_steps + 1)]


@pytest.fixture(scope="module")
def small_beam():
    model = beam("10x2x2")
    return model, observe_truth(model, [E_TRUE])


@pytest.mark.parametrize(
    ("est", "tol"),
    [
        (RoUkf(), 0.01),
        (RoUkf(sigma_points="star"), 0.01),
        (Rls(), 0.01),
        (Lms(), 0.05),
        (BatchLs(), 0.01),
        (BatchLs(refit="each"), 0.01),
    ],
    ids=repr,
)
@pytest.mark.parametrize("prior_mean", [2500.0, 10000.0])
def test_recovers_e_true(small_beam, est, tol, prior_mean):
    model, obs = small_beam
    trace = run(est, model, Prior((prior_mean,), (prior_mean,)), obs)
    assert abs(trace[-1].mean[0] / E_TRUE - 1) < tol
    assert trace[-1].cost.forward_solves > 0


@pytest.mark.parametrize("prior_mean", [2500.0, 10000.0])
def test_full_ukf_recovers_e_true_on_tiny_beam(prior_mean):
    model = beam("6x1x1", n_steps=6)
    obs = observe_truth(model, [E_TRUE])
    est = Ukf()
    trace = run(est, model, Prior((prior_mean,), (prior_mean,)), obs)
    assert abs(trace[-1].mean[0] / E_TRUE - 1) < 0.01
    n = model.reset().size + 1
    assert trace[-1].cost.forward_solves == model.n_steps * (2 * n + 1)


def test_cost_per_step_on_beam(small_beam):
    model, obs = small_beam
    for kind, r in (("simplex", 2), ("star", 3)):
        trace = run(RoUkf(sigma_points=kind), model, Prior((2500.0,), (2500.0,)), obs)
        assert [e.cost.forward_solves for e in trace] == [
            r * k for k in range(1, model.n_steps + 1)
        ]


def test_full_ukf_refuses_a_large_beam():
    model = beam("20x4x4", n_steps=2)
    with pytest.raises(Skipped, match="max_solves = 1500"):
        Ukf().start(model, Prior((2500.0,), (2500.0,)))


@pytest.mark.parametrize(
    ("est", "prior_mean"),
    [
        (RoUkf(), 10000.0),
        (RoUkf(sigma_points="star"), 10000.0),
        # From below, the first (nonlinear, R ~ 1e-12) update locks the rank-2
        # covariance onto a wrong compensating pair; a small random walk frees it.
        (RoUkf(param_noise=0.05), 2500.0),
        (RoUkf(param_noise=0.05), 10000.0),
    ],
    ids=repr,
)
def test_ro_ukf_identifies_two_regions(est, prior_mean):
    """Two slabs along x with different moduli, seen by markers along the top."""
    model = beam(
        "10x2x2",
        n_steps=20,
        markers=8,
        settings={"parameters": "E_regions", "regions": 2},
    )
    truth = np.array([4000.0, 7000.0])
    obs = observe_truth(model, truth)
    trace = run(est, model, Prior.broadcast(prior_mean, prior_mean, 2), obs)
    np.testing.assert_allclose(trace[-1].mean, truth, rtol=0.02)
    r = 3 if est.sigma_points == "simplex" else 5
    assert trace[-1].cost.forward_solves == r * model.n_steps
