"""Estimators of parameter fields: MAP + Laplace and the localized filters.

Checked against what does not share their code: the adjoint gradient
against central differences of the objective (markers on a solid, and a
cloud + the tool's force through the observation models), MAP + Laplace
against the exact posterior of a linear-Gaussian field, the localized
filters against the plain ones where localization is off.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.bodies import FIELD_MARKERS, write_beam_body
from support.toymodels import LinearFieldToy, LinearToy

from idbench import FieldPrior, Observation, Prior, Skipped
from idbench.core.observation_model import Frame
from idbench.observe.cloud import Cloud
from idbench.observe.kinds import Combined, Force
from idbench.observe.observed_model import ObservedModel
from idbench_fem.bodies.description import load_body
from idbench_fem.bodies.mesh import read_mesh
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid_settings import SolidSettings
from idbench_filters import Enkf, Etkf, LocalizedEnkf, LocalizedEtkf, MapLaplace, Ukf
from idbench_filters.laplace import randomized_eigh

K = 4


def run(est, model, prior, data):
    est.start(model, prior)
    out = None
    for k in range(1, model.n_steps + 1):
        out = est.update(k, data.get(k))
    return out


def toy_data(model, theta, sigma=0.05, seed=1):
    rng = np.random.default_rng(seed)
    out = {}
    for k in range(1, model.n_steps + 1):
        u = (k / model.n_steps) * model.A @ theta
        y = model.H @ u + sigma * rng.standard_normal(model.H.shape[0])
        out[k] = Observation(y, sigma, k)
    return out


def exact_posterior(model, prior_mean, prior_cov, data):
    """The linear-Gaussian posterior of theta from all observations."""
    rows = [model.jac(k) for k in data]
    J = np.vstack(rows)
    y = np.concatenate([data[k].values for k in data])
    rinv = 1 / data[1].noise_std**2
    P = np.linalg.inv(np.linalg.inv(prior_cov) + rinv * J.T @ J)
    mean = P @ (np.linalg.solve(prior_cov, prior_mean) + rinv * J.T @ y)
    return mean, P


def test_map_laplace_is_the_exact_posterior_of_a_linear_gaussian_field():
    model = LinearFieldToy(p=12, m=5, n=20, n_steps=K, length=3.0, seed=3)
    truth = np.sin(np.arange(12) / 2.0)
    data = toy_data(model, truth)
    prior = Prior.broadcast(0.0, 0.8, 12)
    field_prior = FieldPrior.of(model.parameter_field, np.zeros(12), 0.8)
    mean, cov = exact_posterior(model, np.zeros(12), field_prior.cov, data)
    est = MapLaplace(transform="identity")
    out = run(est, model, prior, data)
    assert np.allclose(out.mean, mean, atol=1e-10)
    assert np.allclose(est.posterior.cov, cov, atol=1e-12)
    assert np.allclose(out.std, np.sqrt(np.diag(cov)), rtol=1e-10)
    # low rank: the r data-informed directions; 20 observations of 12 cells
    # through 5 values a step leave H_d of rank 5 (u_k = (k/K) A theta)
    low = MapLaplace(transform="identity", rank=5)
    run(low, model, prior, data)
    assert np.allclose(low.posterior.cov, cov, atol=1e-10)
    short = MapLaplace(transform="identity", rank=2)
    run(short, model, prior, data)
    gap = np.linalg.norm(short.posterior.cov - cov)
    assert 0 < gap < np.linalg.norm(field_prior.cov - cov)  # between prior and exact


def test_randomized_eigensolver_finds_the_leading_eigenpairs():
    rng = np.random.default_rng(0)
    Q, _ = np.linalg.qr(rng.standard_normal((60, 60)))
    lam = 10.0 ** -np.arange(60, dtype=float) * 1e3
    H = (Q * lam) @ Q.T
    values, vectors = randomized_eigh(lambda X: H @ X, 60, 6, rng)
    assert np.allclose(values, lam[:6], rtol=1e-8)
    assert np.allclose(np.abs(np.sum(vectors * Q[:, :6], axis=0)), 1, atol=1e-8)


@pytest.fixture(scope="module")
def beam(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("beam")
    path, _ = write_beam_body(tmp, spec="12x3x3", markers=FIELD_MARKERS)
    body = load_body(path)
    mesh = read_mesh(body.mesh.truth)
    settings = SolidSettings(field_cells=8, field_length=0.08)
    return SolidModel(body, mesh, "end", mesh, K, 6, settings)


def fd_gradient(est, xi, h=1e-5):
    e = np.eye(xi.size)
    return np.array([
        (est.evaluate(xi + h * e[j], False).cost
         - est.evaluate(xi - h * e[j], False).cost) / (2 * h)
        for j in range(xi.size)
    ])  # fmt: skip


def test_adjoint_gradient_equals_finite_differences_with_markers(beam):
    model = beam
    p = model.parameters.p
    rng = np.random.default_rng(0)
    true = 5000 * np.exp(0.3 * rng.standard_normal(p))
    u, data = model.reset(), {}
    for k in range(1, K + 1):
        u = model.step(true, k, u)
        y = model.observe(u) + 1e-5 * rng.standard_normal(18)
        data[k] = Observation(y, 1e-5, k)
    est = MapLaplace()
    out = run(est, model, Prior.broadcast(5000.0, 2500.0, p), data)
    xi = 0.5 * (np.log(true) + np.log(5000.0))
    at = est.evaluate(xi)
    fd = fd_gradient(est, xi)
    assert np.linalg.norm(at.gradient - fd) <= 1e-6 * np.linalg.norm(fd)
    # the Jacobian rows give the same gradient (data part) as the adjoint
    assert 1 <= est.iterations <= est.max_iterations
    assert np.all(np.abs(np.log(out.mean / true)) < 0.3)
    # the reported std is the Laplace posterior's, below the prior's
    assert np.all(out.std < 2500.0)


def test_adjoint_gradient_through_a_cloud_and_the_tool_force(tmp_path):
    from support.bodies import write_pulled_box

    write_pulled_box(tmp_path, """
[field]
cells = 4
length = 0.04
""")
    body = load_body(tmp_path / "box.toml")
    mesh = read_mesh(tmp_path / "box.vtu")
    model = SolidModel(body, mesh, "pull", mesh, K, 1)
    p = model.parameters.p
    true = 5000 * np.array([1.0, 2.0, 1.0, 0.7])[:p]
    cloud = Cloud(points=60, noise=1e-4, position=(0.05, 0.01, 0.2),
                  look_at=(0.05, 0.01, 0.0))  # fmt: skip
    force = Force(noise=1e-3)
    obs = Combined((("cloud", cloud), ("force", force)))
    rng = np.random.default_rng(5)
    u, frames = model.reset(), []
    for k in range(1, K + 1):
        u = model.step(true, k, u)
        c = cloud.measure([cloud.sense(model, true, k, u)], rng, 1e-4)[0]
        f = force.measure([force.sense(model, true, k, u)], rng, 1e-3)[0]
        frames.append(Frame(k, Combined.merge([("cloud", c), ("force", f)])))
    seen = ObservedModel(model, obs, frames)
    data = {f.step: Observation(obs.values(f), obs.noise_std(f, 1e-4), f.step)
            for f in frames}  # fmt: skip
    est = MapLaplace(max_iterations=3)
    run(est, seen, Prior.broadcast(5000.0, 2500.0, p), data)
    xi = np.log(true) + 0.2
    at = est.evaluate(xi)
    fd = fd_gradient(est, xi)
    assert np.linalg.norm(at.gradient - fd) <= 1e-5 * np.linalg.norm(fd)
    assert seen.observation_points(1).shape == (63, 3)
    assert np.isnan(seen.observation_points(1)[-3:]).all()  # the force: nowhere


def test_map_laplace_skips_a_model_without_adjoint():
    with pytest.raises(Skipped, match="equilibrium_jvp"):
        MapLaplace().start(LinearToy(p=2), Prior.broadcast(1.0, 1.0, 2))


def test_localized_filters_equal_the_plain_ones_when_off():
    model = LinearFieldToy(p=6, m=4, n=10, n_steps=K, seed=2)
    data = toy_data(model, np.linspace(-1, 1, 6))
    prior = Prior.broadcast(0.0, 1.0, 6)
    for plain, local in ((Enkf, LocalizedEnkf), (Etkf, LocalizedEtkf)):
        a = run(plain(transform="identity", members=20, seed=3), model, prior, data)
        b = run(local(transform="identity", members=20, seed=3, smooth=False),
                model, prior, data)  # fmt: skip
        assert np.allclose(a.mean, b.mean, rtol=1e-12, atol=1e-12)
        assert np.allclose(a.std, b.std, rtol=1e-12, atol=1e-12)
        # a support far beyond the chain: the taper is 1 to O((r/c)^2)
        c = run(local(transform="identity", members=20, seed=3, localization=1e4,
                      smooth=False), model, prior, data)  # fmt: skip
        assert np.allclose(a.mean, c.mean, atol=1e-5)


def test_localization_leaves_far_cells_at_their_prior():
    model = LinearFieldToy(p=12, m=3, n=10, n_steps=K, seed=2)
    model._points[:] = [[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]]  # all at one end
    data = toy_data(model, np.linspace(-1, 1, 12))
    prior = Prior.broadcast(0.0, 1.0, 12)
    est = LocalizedEtkf(transform="identity", members=30, seed=1, localization=4.0)
    out = run(est, model, prior, data)
    start = LocalizedEtkf(transform="identity", members=30, seed=1, localization=4.0)
    start.start(model, prior)
    xi0 = start.ensemble[:, model.A.shape[0]:]
    far = slice(7, 12)  # beyond 4 m of every observation point
    assert np.allclose(out.mean[far], xi0.mean(axis=0)[far], atol=1e-12)
    assert not np.allclose(out.mean[:3], xi0.mean(axis=0)[:3], atol=1e-3)


def test_full_ukf_skips_a_large_field_saying_so():
    model = LinearFieldToy(p=30, m=3, n=4, n_steps=K)
    est = Ukf(transform="identity")
    with pytest.raises(Skipped, match="field of 30 parameters"):
        est.start(model, Prior.broadcast(0.0, 1.0, 30))
    assert est.estimate_solves(4, 30, K) == 0
