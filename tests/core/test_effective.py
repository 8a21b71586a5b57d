"""Effective parameters per load level, checked against exact answers and scipy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from idbench.calibrate.effective import effective_path
from idbench.core.interfaces import ModelSpec
from idbench.registry.registry import build_registry
from idbench.truth.simulate import simulate_path, simulate_truth

E_TRUE = 5000.0


@pytest.fixture(scope="module")
def registry():
    return build_registry()


def beam(registry, mesh, scenario="bend-y", steps=4, **kw):
    scenario = registry.scenario(scenario)
    spec = ModelSpec(mesh=mesh, scenario=scenario, n_steps=steps, **kw)
    return registry.model("svk-beam")(spec)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path))


@pytest.mark.parametrize("scenario", ["bend-y", "stretch-x"])
def test_same_mesh_recovers_the_true_modulus_at_every_step(registry, scenario):
    model = beam(registry, "6x2x2", scenario)
    truth = simulate_truth(model, np.array([E_TRUE]), cache=False)
    path = effective_path(model, truth.grid, [2.0 * E_TRUE])  # start far off
    np.testing.assert_allclose(path.theta[:, 0], E_TRUE, rtol=1e-6)
    assert np.all(path.residual < 1e-9)
    np.testing.assert_allclose(path.states, truth.states, atol=1e-9)


def test_region_moduli_are_recovered_when_the_model_is_exact(registry):
    model = beam(
        registry, "8x2x2", settings={"parameters": "E_regions", "regions": 2}
    )
    theta = np.array([E_TRUE, 3.0 * E_TRUE])
    truth = simulate_truth(model, theta, cache=False)
    path = effective_path(model, truth.grid, [E_TRUE, E_TRUE])
    np.testing.assert_allclose(path.theta, np.tile(theta, (4, 1)), rtol=1e-5)


def test_one_step_fit_on_markers_agrees_with_scipy_least_squares(registry):
    truth = simulate_truth(beam(registry, "16x3x3", steps=1, markers=4), [E_TRUE])
    model = beam(registry, "6x2x2", steps=1, markers=4)
    path = effective_path(model, truth.observations, [E_TRUE], using="observations")

    def misfit(log_e):
        state = simulate_path(model, np.exp(log_e))[-1]
        return model.observe(state) - truth.observations[0]

    fit = least_squares(misfit, [np.log(E_TRUE)], x_scale=1.0, xtol=1e-12, ftol=1e-14)
    assert path.theta[0, 0] == pytest.approx(np.exp(fit.x[0]), rel=1e-5)


def test_a_coarse_mesh_is_too_stiff_in_bending(registry):
    truth = simulate_truth(beam(registry, "24x4x4"), [E_TRUE])
    path = effective_path(beam(registry, "8x2x2"), truth.grid, [E_TRUE])
    assert np.all(path.theta[:, 0] < 0.8 * E_TRUE)


def test_bad_target_and_mode_are_rejected(registry):
    model = beam(registry, "4x1x1")
    with pytest.raises(ValueError, match="target has 3 steps, the model has 4"):
        effective_path(model, np.zeros((3, 10, 3)), [E_TRUE])
    with pytest.raises(ValueError, match="using = 'nodes'"):
        effective_path(model, np.zeros((4, 10, 3)), [E_TRUE], using="nodes")  # type: ignore[arg-type]
