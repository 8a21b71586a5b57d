"""The compiled SVK kernel equals the numpy kinematics and forces to round-off."""

from __future__ import annotations

import importlib
import sys

import numpy as np
import pytest
from support.beams import beam_model

from idbench_fem.bodies import box as meshes
from idbench_fem.bodies.regions import region_nodes
from idbench_fem.fem import kernels
from idbench_fem.fem.svk_assembly import Assembler
from idbench_fem.models.beam_scenarios import SCENARIOS

numba = pytest.importorskip("numba")  # in the test extra; optional for users


def _pair(spec: str = "6x2x2") -> tuple[Assembler, Assembler]:
    beam = meshes.parse(spec)
    free = np.ones(len(beam.points), dtype=bool)
    free[region_nodes(beam, meshes.clamped_face(beam))] = False
    args = (beam.points, beam.tets, free, 0.45)
    return Assembler(*args, compiled=True), Assembler(*args, compiled=False)


def _close(a: np.ndarray, b: np.ndarray, rtol: float = 1e-13) -> None:
    assert a.shape == b.shape
    assert np.abs(a - b).max() <= rtol * np.abs(b).max()


@pytest.mark.parametrize("stack", [False, True])
def test_compiled_kinematics_and_forces_equal_numpy(stack):
    fast, slow = _pair()
    rng = np.random.default_rng(7)
    r = 3 if stack else 1
    # large strains (|H| ~ 0.1-0.5) and moduli varying by element and row
    X = 0.02 * rng.standard_normal((r, fast.n_free))
    mod = 5000.0 * np.exp(0.5 * rng.standard_normal((r, fast.n_elements)))
    if not stack:
        X, mod = X[0], mod[0]
    a, b = fast.kinematics(X, mod), slow.kinematics(X, mod)
    assert a.forces is not None and b.forces is None
    for name in ("F", "S", "det"):
        _close(getattr(a, name), getattr(b, name))
    _close(fast.forces(a), slow.forces(b))
    # what builds on F and S (tangent, regional forces) sees the same numbers
    if not stack:
        pat = slow.pattern(upper=False)
        _close(fast.tangent_data(a, mod, pat), slow.tangent_data(b, mod, pat))
        regions = np.arange(fast.n_elements) % 3
        _close(fast.region_forces(a, regions, 3), slow.region_forces(b, regions, 3))


def test_one_modulus_for_a_stack_of_states():
    fast, slow = _pair()
    X = 0.01 * np.random.default_rng(1).standard_normal((4, fast.n_free))
    mod = np.full(fast.n_elements, 3000.0)
    _close(fast.forces(fast.kinematics(X, mod)), slow.forces(slow.kinematics(X, mod)))


def test_forces_returns_a_copy():
    fast, _ = _pair()
    kin = fast.kinematics(np.zeros(fast.n_free) + 1e-3, np.ones(fast.n_elements))
    f = fast.forces(kin)
    f += 1.0
    assert not np.array_equal(fast.forces(kin), f)


def test_a_load_path_equals_the_numpy_one(monkeypatch):
    """Newton with either kernel: the same states to the Newton tolerance."""
    states = []
    for flag in ("1", "0"):
        monkeypatch.setenv(kernels.ENV, flag)
        model = beam_model(meshes.parse("6x2x2"), SCENARIOS[1], n_steps=4)
        assert model._asm.compiled is (flag == "1")
        u = model.reset()
        for k in range(1, 5):
            u = model.step(np.array([5000.0]), k, u)
        states.append(u)
    _close(states[0], states[1], rtol=1e-9)


def test_switched_off_by_the_environment(monkeypatch):
    monkeypatch.setenv(kernels.ENV, "0")
    assert not kernels.available()
    monkeypatch.setenv(kernels.ENV, "1")
    assert kernels.available()


@pytest.mark.parametrize("shape", [(5,), (2, 5), (2, 3, 4)])
def test_a_state_of_the_wrong_size_is_refused(shape):
    """The kernel reads without bounds checks: a wrong size must not reach it."""
    fast, _ = _pair()
    with pytest.raises(ValueError, match="state has shape"):
        fast.kinematics(np.zeros(shape), np.ones(fast.n_elements))


def test_numba_that_does_not_import_means_numpy(tmp_path, monkeypatch):
    fake = tmp_path / "numba"
    fake.mkdir()
    (fake / "__init__.py").write_text(
        "raise ImportError('Numba needs NumPy 2.3 or less')"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "numba")
    kernels._numba_works.cache_clear()
    try:
        assert not kernels.available()
        beam = beam_model(meshes.parse("4x1x1"), SCENARIOS[1], n_steps=2)
        assert not beam._asm.compiled
        beam.step(np.array([5000.0]), 1, beam.reset())
    finally:
        kernels._numba_works.cache_clear()


def test_nowhere_to_cache_compiles_without_a_cache(monkeypatch, caplog):
    from idbench_fem.fem import element_loops

    real = numba.njit

    def njit(*args, **kwargs):
        if kwargs.get("cache"):
            raise RuntimeError(
                "cannot cache function '_svk_loop': no locator available"
            )
        return real(*args, **kwargs)

    monkeypatch.setattr(numba, "njit", njit)
    try:
        with caplog.at_level("WARNING"):
            importlib.reload(element_loops)  # the loops, compiled without a cache
        assert "numba cannot cache svk_kinematics" in caplog.text
        fast, slow = _pair("4x1x1")
        X = np.full(fast.n_free, 1e-3)
        mod = np.ones(fast.n_elements)
        _close(
            fast.forces(fast.kinematics(X, mod)), slow.forces(slow.kinematics(X, mod))
        )
    finally:
        monkeypatch.undo()
        importlib.reload(element_loops)


def test_shared_element_steps_equal_their_numpy_forms():
    """The compiled steps both kernels use (element_loops) match numpy on one tet."""
    from idbench_fem.fem import element_loops as el

    rng = np.random.default_rng(3)
    grads = rng.standard_normal((1, 4, 3))
    dofs = np.array([[0, 1, 2, -1, -1, -1, 3, 4, 5, 6, 7, 8]])
    u = rng.standard_normal(9)
    ue = np.empty(12)
    el.gather(u, dofs, 0, ue)
    np.testing.assert_array_equal(ue, np.where(dofs[0] >= 0, u[dofs[0]], 0.0))
    H = ue.reshape(4, 3).T @ grads[0]
    F = np.array(el.gradient(ue, grads, 0, 1.0)).reshape(3, 3)
    np.testing.assert_allclose(el.gradient(ue, grads, 0, 0.0), H.ravel(), atol=1e-14)
    np.testing.assert_allclose(F, np.eye(3) + H, atol=1e-14)
    J = np.linalg.det(F)
    inv = np.array(el.inverse(el.cofactors(tuple(F.ravel())), J)).reshape(3, 3)
    np.testing.assert_allclose(inv, np.linalg.inv(F), rtol=1e-12, atol=1e-12)
    sym = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    C_inv = inv @ inv.T
    np.testing.assert_allclose(
        el.gram(tuple(inv.ravel())), [C_inv[i, j] for i, j in sym]
    )
    E = 0.5 * (F.T @ F - np.eye(3))
    lam, mu, m = 0.8, 0.3, 2.5
    S = m * (lam * np.trace(E) * np.eye(3) + 2 * mu * E)
    s = el.svk_stress(tuple(E[i, j] for i, j in sym), m, lam, mu)
    np.testing.assert_allclose(s, [S[i, j] for i, j in sym], atol=1e-14)
    Fe, Se = np.empty((3, 3)), np.empty((3, 3))
    el.store(Fe, Se, tuple(F.ravel()), s)
    np.testing.assert_array_equal(Fe, F)
    np.testing.assert_allclose(Se, S, atol=1e-14)
    force = np.zeros(9)
    el.add_force(force, dofs, grads, 0, 0.7, tuple(F.ravel()), s)
    fe = (grads[0] @ (0.7 * F @ S).T).ravel()  # f_ai = V (F S)_iJ G_aJ
    expected = np.zeros(9)
    np.add.at(expected, dofs[0][dofs[0] >= 0], fe[dofs[0] >= 0])
    np.testing.assert_allclose(force, expected, atol=1e-13)
