"""Model-error-aware RO-UKF and the misfit estimate it is sized from."""

from __future__ import annotations

import numpy as np
import pytest
from support.helpers import SIGMA, make_data
from support.toymodels import LinearToy, SensitiveLinearToy

from idbench import Observation, Prior
from idbench.estimate.posterior import model_error
from idbench_filters import RoUkf


def exact(model, prior, obs, var):
    info = np.diag(1.0 / np.asarray(prior.std) ** 2)
    rhs = info @ np.asarray(prior.mean)
    for k, o in obs.items():
        J = model.jac(k)
        info = info + J.T @ J / var
        rhs = rhs + J.T @ o.values / var
    P = np.linalg.inv(info)
    return P @ rhs, np.sqrt(np.diag(P))


@pytest.mark.parametrize("p", [1, 2])
def test_model_error_adds_to_the_noise_variance(p):
    model = SensitiveLinearToy(p=p, n=4, m=3, n_steps=6, seed=p)
    prior = Prior((1.0, 0.5)[:p], (2.0, 1.5)[:p])
    obs = make_data(model, np.array([3.0, -1.5][:p]), 1)
    est = RoUkf(transform="identity", model_error=0.2)
    est.start(model, prior)
    for k in range(1, 7):
        e = est.update(k, obs.get(k))
    mean, std = exact(model, prior, obs, SIGMA**2 + 0.2**2)
    np.testing.assert_allclose(e.mean, mean, rtol=1e-8)
    np.testing.assert_allclose(e.std, std, rtol=1e-8)
    plain = RoUkf(transform="identity")
    plain.start(model, prior)
    for k in range(1, 7):
        f = plain.update(k, obs.get(k))
    assert np.all(e.std > 3 * f.std)


@pytest.mark.parametrize("bad", [-1e-3, float("inf")])
def test_bad_model_error(bad):
    with pytest.raises(ValueError, match=f"model_error = {bad!r}"):
        RoUkf(model_error=bad)


def test_misfit_of_a_wrong_model_is_its_rms_residual():
    """Data from A theta + d (a fixed discrepancy): e = RMS(d) beyond the noise."""
    model = LinearToy(p=1, n=4, m=3, n_steps=6, seed=1)
    theta = np.array([2.0])
    rng = np.random.default_rng(0)
    d = rng.normal(size=(6, 3)) * 0.01
    stream = [Observation(model.jac(k) @ theta + d[k - 1], 0.0, k) for k in range(1, 7)]
    assert model_error(model, theta, stream) == pytest.approx(
        np.sqrt(np.mean(d**2)), rel=1e-12
    )
    # the noise variance the observations declare is taken out
    noisy = [Observation(o.values, 0.005, o.step) for o in stream]
    assert model_error(model, theta, noisy) == pytest.approx(
        np.sqrt(np.mean(d**2) - 0.005**2), rel=1e-12
    )
    # a perfect model: 0, and only observed steps count
    exact_stream = [
        None,
        *(Observation(model.jac(k) @ theta, 0.0, k) for k in range(2, 7)),
    ]
    assert model_error(model, theta, exact_stream) == pytest.approx(0.0, abs=1e-15)
    with pytest.raises(ValueError, match="no observations"):
        model_error(model, theta, [None] * 6)
