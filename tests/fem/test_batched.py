"""Batched steps of the beam (step_many) and the filters that use them."""

from __future__ import annotations

import numpy as np
import pytest
from support.beams import beam_model
from support.toymodels import LinearToy

import idbench
from idbench import ModelFailure, ModelSpec, Observation, Prior
from idbench.registry.testing import WithoutStepMany, check_batch_model
from idbench_fem.bodies import box
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_filters import RoUkf, Ukf
from idbench_filters.common import advance_many

E_TRUE = 5000.0


def _beam(spec="6x2x2", n_steps=6, **kw):
    return beam_model(box.parse(spec), SCENARIOS[0], n_steps=n_steps, **kw)


def _path(model, theta, steps):
    states = [model.reset()]
    for k in range(1, steps + 1):
        states.append(model.step(np.asarray(theta, float), k, states[-1]))
    return states


def test_beam_conforms_to_batch_model():
    model = _beam()
    assert isinstance(model, idbench.BatchModel)
    thetas = E_TRUE * np.array([[1.0], [0.5], [2.0], [1.01]])
    check_batch_model(model, thetas, steps=3, rtol=1e-6)


def test_regions_conform_to_batch_model():
    model = _beam(parameters="E_regions", options={"regions": 2})
    thetas = np.array([[5000.0, 5000.0], [3000.0, 8000.0], [5100.0, 4900.0]])
    check_batch_model(model, thetas, steps=2, rtol=1e-6)


@pytest.mark.parametrize("spread", [0.5, 0.02, 0.0])
def test_every_row_meets_the_newton_tolerance(spread):
    model = _beam()
    rng = np.random.default_rng(3)
    k = 4
    start = _path(model, [E_TRUE], k - 1)[-1]
    thetas = E_TRUE * np.exp(spread * rng.normal(size=(7, 1)))
    states = start + 1e-7 * rng.normal(size=(7, model.n_state))
    out = model.step_many(thetas, k, states)
    tol = model.rtol * np.linalg.norm(model.external_force(k))
    for i in range(7):
        ref = model.step(thetas[i], k, states[i])
        assert np.linalg.norm(model.residual(thetas[i], k, out[i])) <= tol
        assert np.abs(out[i] - ref).max() <= 1e-6 * np.abs(ref).max()


def test_nearby_sigma_points_share_one_factorization():
    model = _beam()
    k = 3
    start = _path(model, [E_TRUE], k - 1)[-1]
    thetas = E_TRUE * (1 + 1e-6 * np.arange(9.0))[:, None]
    before = model.factorizations
    c0 = model.cost()
    model.step_many(thetas, k, np.tile(start, (9, 1)))
    factors = model.factorizations - before
    its_one = (model.cost() - c0).newton_its  # counted as Newton iterations too
    f0 = model.factorizations
    model.step(thetas[0], k, start)
    assert factors == model.factorizations - f0  # the anchor's Newton only
    assert its_one >= factors
    assert (model.cost() - c0).forward_solves == 10


def test_step_many_rejects_bad_input():
    model = _beam()
    u = model.reset()
    with pytest.raises(ValueError, match="thetas has shape"):
        model.step_many(np.array([5000.0]), 1, u[None])
    with pytest.raises(ValueError, match="states has shape"):
        model.step_many(np.array([[5000.0]]), 1, u)
    with pytest.raises(ModelFailure, match="positive"):
        model.step_many(np.array([[5000.0], [-1.0]]), 1, np.stack([u, u]))


def test_advance_many_falls_back_to_step_on_failure():
    toy = LinearToy(p=1)
    calls = []

    def failing(thetas, k, states):
        calls.append(k)
        raise ModelFailure("no", step=k)

    toy.step_many = failing
    thetas = np.array([[1.0], [2.0]])
    out = advance_many(toy, thetas, 2, np.zeros((2, 4)))
    assert calls == [2]
    np.testing.assert_allclose(out, [toy.A @ t * 2 / 6 for t in thetas])
    assert [c[0] for c in toy.calls] == [2, 2]


def _observations(model, every=2, noise=1e-4, seed=0):
    rng = np.random.default_rng(seed)
    obs, u = {}, model.reset()
    for k in range(1, model.n_steps + 1):
        u = model.step(np.array([E_TRUE] * model.parameters.p), k, u)
        if k % every == 0:
            y = model.observe(u) + noise * rng.normal(size=model.observe(u).shape)
            obs[k] = Observation(values=y, noise_std=noise, step=k)
    return obs


def _run(est, model, prior, obs):
    est.start(model, prior)
    return [est.update(k, obs.get(k)) for k in range(1, model.n_steps + 1)]


@pytest.mark.parametrize(
    ("est", "parameters"),
    [(RoUkf(), "E"), (RoUkf(sigma_points="star"), "E"), (RoUkf(), "E_regions")],
    ids=["simplex", "star", "regions"],
)
def test_ro_ukf_with_and_without_step_many_agree(est, parameters):
    reg = idbench.build_registry()
    spec = ModelSpec(
        mesh="8x2x2", scenario=reg.scenario("bend-y"), n_steps=8,
        settings={"parameters": parameters},
    )  # fmt: skip
    model = reg.model("svk-beam")(spec)
    p = model.parameters.p
    obs = _observations(model)
    prior = Prior((2500.0,) * p, (2500.0,) * p)
    stats0 = model.batch_stats.pairs
    batched = _run(est, model, prior, obs)
    assert model.batch_stats.pairs - stats0 == 8 * est.solves_per_step
    looped = _run(est, WithoutStepMany(model), prior, obs)
    for a, b in zip(batched, looped, strict=True):
        np.testing.assert_allclose(a.mean, b.mean, rtol=1e-8)
        np.testing.assert_allclose(a.std, b.std, rtol=1e-6)
        assert a.cost.forward_solves == b.cost.forward_solves


def test_full_ukf_with_and_without_step_many_agree():
    reg = idbench.build_registry()
    spec = ModelSpec(mesh="4x1x1", scenario=reg.scenario("bend-y"), n_steps=6)
    model = reg.model("svk-beam")(spec)
    obs = _observations(model, every=1)
    prior = Prior((2500.0,), (2500.0,))
    batched = _run(Ukf(), model, prior, obs)
    assert model.batch_stats.calls == 6
    looped = _run(Ukf(), WithoutStepMany(model), prior, obs)
    for a, b in zip(batched, looped, strict=True):
        np.testing.assert_allclose(a.mean, b.mean, rtol=1e-8)
        np.testing.assert_allclose(a.std, b.std, rtol=1e-6)
    # and far from the prior: the estimate moved
    assert abs(batched[-1].mean[0] / E_TRUE - 1) < 0.05


def test_a_run_does_not_depend_on_the_runs_before_it():
    reg = idbench.build_registry()
    spec = ModelSpec(mesh="6x2x2", scenario=reg.scenario("bend-y"), n_steps=6)
    model = reg.model("svk-beam")(spec)
    obs = _observations(model)
    prior = Prior((2500.0,), (2500.0,))
    first = _run(RoUkf(), model, prior, obs)
    c0 = model.cost()
    second = _run(RoUkf(), model, prior, obs)
    fresh = reg.model("svk-beam")(spec)
    third = _run(RoUkf(), fresh, prior, obs)
    for a, b, c in zip(first, second, third, strict=True):
        assert np.array_equal(a.mean, b.mean) and np.array_equal(a.mean, c.mean)
    assert (model.cost() - c0) == fresh.cost()


def test_line_residuals_equal_assembled_ones():
    # p = 1: residuals of the predictions from the cubic along the line equal
    # the assembled residuals to round-off, and det F > 0 is judged alike
    from idbench_fem.fem.predictions import line_residuals, residuals

    model = _beam("8x2x2")
    k = 4
    u_a = _path(model, [E_TRUE], k)[-1]
    rng = np.random.default_rng(5)
    s = rng.normal(size=model.n_state) * 1e-2 * np.abs(u_a).max() / E_TRUE
    t = np.concatenate([[0.0], E_TRUE * rng.uniform(-0.3, 0.3, 20)])
    thetas = E_TRUE + t
    f_ext = model.external_force(k)
    asm, unit = model.assembler, model.unit_moduli
    ok, norms, res = line_residuals(asm, unit, u_a, s, t, thetas, f_ext)
    preds = u_a + t[:, None] * s
    mods = np.stack([model.element_moduli(np.array([th]), k) for th in thetas])
    ok_ref, norms_ref, res_ref = residuals(asm, preds, mods, f_ext)
    np.testing.assert_array_equal(ok, ok_ref)
    scale = np.linalg.norm(f_ext)  # the Newton tolerance is 1e-8 of it
    assert np.abs(res - res_ref).max() <= 1e-10 * scale
    np.testing.assert_allclose(norms, norms_ref, rtol=0, atol=1e-10 * scale)
    # a prediction that inverts an element is caught from the cubic det F too
    far = np.array([0.0, 50.0 * E_TRUE])
    ok_far, _, _ = line_residuals(asm, unit, u_a, s * 40, far, E_TRUE + far, f_ext)
    mods_far = np.stack([model.element_moduli(np.array([E_TRUE]), k)] * 2)
    ok_far_ref, _, _ = residuals(asm, u_a + far[:, None] * s * 40, mods_far, f_ext)
    np.testing.assert_array_equal(ok_far, ok_far_ref)
    assert not ok_far[-1]


def test_line_residuals_when_every_prediction_is_the_anchor():
    from idbench_fem.fem.predictions import line_residuals, residuals

    model = _beam("8x2x2")
    u_a = _path(model, [E_TRUE], 2)[-1]
    f_ext = model.external_force(2)
    s = np.full(model.n_state, 1e9)  # any scale: t = 0 never uses it
    t = np.zeros(12)
    asm, unit = model.assembler, model.unit_moduli
    ok, norms, res = line_residuals(asm, unit, u_a, s, t, E_TRUE + t, f_ext)
    mods = np.stack([model.element_moduli(np.array([E_TRUE]), 2)] * 12)
    ok_ref, _, res_ref = residuals(asm, np.tile(u_a, (12, 1)), mods, f_ext)
    np.testing.assert_array_equal(ok, ok_ref)
    np.testing.assert_allclose(res, res_ref, rtol=0, atol=1e-14)
    assert np.all(norms <= model.rtol * np.linalg.norm(f_ext))  # converged


@pytest.mark.parametrize("beta", [0.0, 1.0, 2.0, 0.5])
def test_prediction_steps_agree_to_first_order(beta):
    from idbench_fem.fem.predictions import prediction_steps

    theta_a = np.array([5000.0, 3000.0])
    h = np.array([[1e-4, -2e-4]]) * theta_a
    t = prediction_steps(theta_a, theta_a + h, beta)
    np.testing.assert_allclose(t, h, rtol=5e-4)


def test_prediction_in_inverse_theta_is_exact_for_a_linear_model():
    """u = c / theta: S = -u_a / theta_a, and u_a + S t equals u(theta) for any
    theta, however far (the linear-in-theta prediction does not)."""
    from idbench_fem.fem.predictions import prediction_steps

    c, theta_a = np.array([2.0, -1.0, 0.5]), np.array([5000.0])
    u_a = c / theta_a
    S = (-u_a / theta_a)[:, None]
    thetas = np.array([[1000.0], [5000.0], [40000.0]])
    exact = c / thetas
    pred = u_a + prediction_steps(theta_a, thetas, 2.0) @ S.T
    np.testing.assert_allclose(pred, exact, rtol=1e-12)
    linear = u_a + prediction_steps(theta_a, thetas, 0.0) @ S.T
    assert np.abs(linear - exact).max() > 0.5 * np.abs(exact).max()
