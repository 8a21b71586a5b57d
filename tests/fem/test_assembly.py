"""SVK residual and tangent: finite differences and the scikit-fem form oracle."""

from __future__ import annotations

import numpy as np
import pytest
from support.beams import beam_model
from support.oracles import svk_forms, v01_kernel

import idbench
from idbench_fem.bodies import box
from idbench_fem.models.beam_scenarios import SCENARIOS


def _model(nu=0.3, solver=None, spec="4x2x2"):
    options = {"regions": 2} | ({"solver": solver} if solver else {})
    return beam_model(
        box.parse(spec),
        SCENARIOS[3],
        n_steps=5,
        nu=nu,
        parameters="E_regions",
        options=options,
    )


def _state(m, scale=0.004, seed=1):
    return np.random.default_rng(seed).normal(size=m.n_state) * scale


@pytest.mark.parametrize("nu", [0.3, 0.45, -0.2])
def test_tangent_is_derivative_of_residual(nu):
    m = _model(nu)
    theta = np.array([3000.0, 7000.0])
    u = _state(m)
    K = m.tangent(theta, u)
    rng = np.random.default_rng(2)
    for _ in range(3):
        d = rng.normal(size=m.n_state)
        h = 1e-6
        fd = (m.residual(theta, 3, u + h * d) - m.residual(theta, 3, u - h * d)) / (
            2 * h
        )
        np.testing.assert_allclose(fd, K @ d, rtol=0, atol=1e-7 * np.abs(K @ d).max())
    assert abs(K - K.T).max() == 0.0


@pytest.mark.parametrize("nu", [0.3, 0.45])
def test_matches_scikit_fem_forms(nu):
    m = _model(nu)
    theta = np.array([3000.0, 7000.0])
    u = _state(m)
    r = m.internal_force(theta, u)
    K = m.tangent(theta, u).toarray()
    free = np.setdiff1d(np.arange(m.n_nodes), m.fixed_nodes)
    r_ref, K_ref = svk_forms.residual_and_tangent(
        m.mesh_data.points,
        m.mesh_data.tets,
        free,
        m.displacement_field(u),
        theta[m.element_regions],
        nu,
    )
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-13 * np.abs(r_ref).max())
    np.testing.assert_allclose(K, K_ref.toarray(), rtol=0, atol=1e-13 * np.abs(K).max())


def test_upper_and_full_patterns_agree():
    pytest.importorskip("pypardiso")
    u = None
    mats = []
    for solver in ("pardiso", "scipy"):
        m = _model(solver=solver)
        u = _state(m) if u is None else u
        mats.append(m.tangent(np.array([3000.0, 7000.0]), u).toarray())
    np.testing.assert_allclose(
        mats[0], mats[1], rtol=0, atol=1e-14 * abs(mats[0]).max()
    )


def test_green_lagrange_is_accurate_at_small_strain():
    # (H + H^T + H^T H)/2 keeps digits that (F^T F - I)/2 loses
    m = _model()
    u = _state(m, scale=1e-15)  # |H| ~ 3e-13: (F^T F - I)/2 would keep ~3 digits
    r = m.internal_force(np.array([1.0, 1.0]), u)
    K = m.tangent(np.array([1.0, 1.0]), np.zeros(m.n_state))
    np.testing.assert_allclose(r, K @ u, rtol=0, atol=1e-11 * np.abs(K @ u).max())


def test_internal_force_is_linear_in_E():
    m = _model()
    u = _state(m)
    f1 = m.internal_force(np.array([1.0, 1.0]), u)
    f2 = m.internal_force(np.array([2500.0, 2500.0]), u)
    np.testing.assert_allclose(f2, 2500.0 * f1, rtol=1e-13, atol=1e-18)


def test_registry_provides_the_model():
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    spec = idbench.ModelSpec(mesh="4x2x2", scenario=reg.scenario("bend-y"), n_steps=3)
    model = reg.model("svk-beam")(spec)
    assert isinstance(model, idbench.SensitiveModel)
    assert model.parameters.names == ("E",)


@pytest.mark.parametrize("nu", [0.3, 0.45, -0.2])
def test_tangent_blocks_equal_the_old_kernel(nu):
    m = _model(nu)
    asm = m._asm
    rng = np.random.default_rng(5)
    modulus = rng.uniform(1000.0, 9000.0, asm.n_elements)
    kin = asm.kinematics(_state(m, scale=0.02), modulus)
    old = v01_kernel.old_element_tangents(asm, kin, modulus).reshape(-1, 4, 3, 4, 3)
    blocks = asm.element_tangent_blocks(kin, modulus)
    ia, ib = np.triu_indices(4)
    new = blocks.transpose(3, 0, 1, 2)  # (T, 10, 3, 3)
    ref = old[:, ia, :, ib, :].transpose(1, 0, 2, 3)  # (T, 10, 3, 3): K[a, i, b, k]
    np.testing.assert_allclose(new, ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    # the lower blocks the kernel skips are the transposes of the upper ones
    np.testing.assert_allclose(
        old[:, ib, :, ia, :].transpose(1, 0, 3, 2),
        ref,
        rtol=0,
        atol=1e-13 * np.abs(ref).max(),
    )
    # and the assembled matrix equals the old element matrices scattered densely
    dense = np.zeros((m.n_state, m.n_state))
    ed = asm.element_dofs
    for t in range(asm.n_elements):
        ok = ed[t] >= 0
        dense[np.ix_(ed[t][ok], ed[t][ok])] += old[t].reshape(12, 12)[np.ix_(ok, ok)]
    for upper in (True, False):
        pat = asm.pattern(upper)
        got = pat.matrix(asm.tangent_data(kin, modulus, pat)).toarray()
        np.testing.assert_allclose(got, dense, rtol=0, atol=1e-13 * abs(dense).max())
