"""Hyperelastic laws: derivatives, closed forms, limits, and the P1 kernel contract."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar
from support.oracles import general_law, svk_forms

from idbench_fem.fem.materials import (
    LAWS,
    NeoHookean,
    Svk,
    deformation_from_strain,
    green_lagrange,
    make_material,
    mandel,
)

LAW_CLASSES = [Svk, NeoHookean]


def _random_F(n, scale, seed=0):
    rng = np.random.default_rng(seed)
    return np.eye(3) + scale * rng.normal(size=(n, 3, 3))


def _sym(i, j):
    d = np.zeros((3, 3))
    d[i, j] += 0.5
    d[j, i] += 0.5
    return d


@pytest.mark.parametrize("law", LAW_CLASSES)
def test_stress_is_derivative_of_energy(law):
    m = law(E=3000.0, nu=0.45)
    E = green_lagrange(_random_F(5, 0.15))
    S = m.stress(deformation_from_strain(E))
    h = 1e-6
    for i in range(3):
        for j in range(3):
            d = _sym(i, j)
            Wp = m.energy(deformation_from_strain(E + h * d))
            Wm = m.energy(deformation_from_strain(E - h * d))
            np.testing.assert_allclose(
                (Wp - Wm) / (2 * h), S[:, i, j], rtol=1e-6, atol=1e-6 * abs(S).max()
            )


@pytest.mark.parametrize("law", LAW_CLASSES)
def test_first_piola_is_derivative_of_energy_in_F(law):
    # independent of the E parametrisation: P = dW/dF = F S, F not symmetric
    m = law(E=2.0, nu=0.3)
    F = _random_F(4, 0.2, seed=3)
    P = np.matmul(F, m.stress(F))
    h = 1e-6
    for i in range(3):
        for j in range(3):
            d = np.zeros((3, 3))
            d[i, j] = h
            fd = (m.energy(F + d) - m.energy(F - d)) / (2 * h)
            np.testing.assert_allclose(fd, P[:, i, j], rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("law", LAW_CLASSES)
def test_tangent_is_derivative_of_stress(law):
    m = law(E=5.0, nu=0.45)
    E = green_lagrange(_random_F(4, 0.15, seed=1))
    C = m.tangent(deformation_from_strain(E))
    h = 1e-6
    for k in range(3):
        for l in range(3):  # noqa: E741
            d = _sym(k, l)
            fd = (
                m.stress(deformation_from_strain(E + h * d))
                - m.stress(deformation_from_strain(E - h * d))
            ) / (2 * h)
            np.testing.assert_allclose(fd, C[..., k, l], rtol=1e-6, atol=1e-6 * 5)
    # major and minor symmetries
    np.testing.assert_allclose(C, C.transpose(0, 3, 4, 1, 2), atol=1e-12)
    np.testing.assert_allclose(C, C.transpose(0, 2, 1, 3, 4), atol=1e-12)


@pytest.mark.parametrize("law", LAW_CLASSES)
def test_mandel_tangent_maps_mandel_strain_to_mandel_stress(law):
    m = law(E=1.0, nu=0.4)
    F = _random_F(3, 0.1, seed=2)
    C = m.tangent(F)
    D = m.mandel_tangent(F)
    dE = green_lagrange(_random_F(3, 0.1, seed=5))
    dS = np.einsum("nijkl,nkl->nij", C, dE)
    np.testing.assert_allclose(np.einsum("nab,nb->na", D, mandel(dE)), mandel(dS))
    np.testing.assert_allclose(D, D.transpose(0, 2, 1), atol=1e-14)


def _closed_form_uniaxial(m, stretch):
    """Lateral stretch s and axial S11 with free lateral faces (S22 = S33 = 0)."""
    lam, mu = m.lam, m.mu
    if isinstance(m, Svk):
        e1 = 0.5 * (stretch**2 - 1)
        e2 = -lam * e1 / (2 * (lam + mu))  # S22 = lam (e1 + 2 e2) + 2 mu e2 = 0
        s = np.sqrt(1 + 2 * e2)
        return s, lam * (e1 + 2 * e2) + 2 * mu * e1
    # neo-Hookean, C^-1 = diag(1/l^2, 1/s^2, 1/s^2), ln J = ln(l s^2):
    # S22 = mu (1 - 1/s^2) + lam ln(l s^2)/s^2 = 0  <=>  mu (s^2 - 1) + lam ln(l s^2)
    s = brentq(lambda s: mu * (s**2 - 1) + lam * np.log(stretch * s**2), 0.2, 2.0)
    lnJ = np.log(stretch * s**2)
    return s, mu * (1 - 1 / stretch**2) + lam * lnJ / stretch**2


@pytest.mark.parametrize("law", LAW_CLASSES)
@pytest.mark.parametrize("stretch", [0.8, 1.3])
def test_uniaxial_energy_minimum_matches_closed_form(law, stretch):
    # independent route: minimise W over the lateral stretch
    m = law(E=4000.0, nu=0.45)
    s_ref, _ = _closed_form_uniaxial(m, stretch)
    res = minimize_scalar(
        lambda s: m.energy(np.diag([stretch, s, s])[None])[0],
        bounds=(0.3, 1.7),
        method="bounded",
        options={"xatol": 1e-12},
    )
    assert res.x == pytest.approx(s_ref, rel=1e-7)


# -- a generic P1 kernel built from the kernel contract, on a real mesh ---------


def _cube(n=2):
    from skfem import MeshTet

    m = MeshTet.init_tensor(*(np.linspace(0.0, 1.0, n + 1),) * 3)
    p, t = m.p.T.copy(), m.t.T.copy()
    x = p[t]
    det = np.einsum("ti,ti->t", x[:, 1] - x[:, 0],
                    np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]))  # fmt: skip
    t[det < 0, 2], t[det < 0, 3] = t[det < 0, 3].copy(), t[det < 0, 2].copy()
    return p, t


def _generic_kernel(law, p, t, u, modulus):
    """Full internal force (3N,) and dense tangent (3N, 3N) of the reference kernel."""
    G, V = general_law.shape_gradients(p, t)
    fe, Ke = general_law.element_kernel(law, u, t, G, V, modulus)
    dofs = (3 * t[:, :, None] + np.arange(3)).reshape(-1, 12)
    n = 3 * len(p)
    f = np.zeros(n)
    np.add.at(f, dofs, fe)
    K = np.zeros((n, n))
    np.add.at(K, (dofs[:, :, None], dofs[:, None, :]), Ke)
    return f, K


def test_generic_kernel_with_svk_matches_scikit_fem_oracle():
    p, t = _cube(2)
    rng = np.random.default_rng(4)
    u = 0.05 * rng.normal(size=p.shape)
    modulus = rng.uniform(1000, 5000, size=len(t))
    f, K = _generic_kernel(Svk(nu=0.45), p, t, u, modulus)
    free = np.arange(len(p))
    r_ref, K_ref = svk_forms.residual_and_tangent(p, t, free, u, modulus, 0.45)
    np.testing.assert_allclose(f, r_ref, atol=1e-12 * abs(r_ref).max())
    np.testing.assert_allclose(K, K_ref.toarray(), atol=1e-12 * abs(K).max())


@pytest.mark.parametrize("law", LAW_CLASSES)
def test_generic_kernel_tangent_is_derivative_of_force(law):
    p, t = _cube(1)
    rng = np.random.default_rng(6)
    u = 0.05 * rng.normal(size=p.shape)
    modulus = np.full(len(t), 2.0)
    _, K = _generic_kernel(law(nu=0.4), p, t, u, modulus)
    d = rng.normal(size=p.shape)
    h = 1e-6
    fp, _ = _generic_kernel(law(nu=0.4), p, t, u + h * d, modulus)
    fm, _ = _generic_kernel(law(nu=0.4), p, t, u - h * d, modulus)
    np.testing.assert_allclose((fp - fm) / (2 * h), K @ d.ravel(), atol=1e-7)


def _uniaxial_cube(law, stretch, n=2):
    """Newton on a P1 cube: symmetry planes x=y=z=0, u_x prescribed on x = 1."""
    p, t = _cube(n)
    fixed = np.zeros((len(p), 3), dtype=bool)
    for c in range(3):
        fixed[np.isclose(p[:, c], 0.0), c] = True
    pulled = np.isclose(p[:, 0], 1.0)
    fixed[pulled, 0] = True
    u = np.zeros_like(p)
    u[pulled, 0] = stretch - 1.0
    u[:, 0] = (stretch - 1.0) * p[:, 0]  # start from a pure axial stretch
    free = ~fixed.ravel()
    modulus = np.full(len(t), law.E)
    for _ in range(30):
        f, K = _generic_kernel(law, p, t, u, modulus)
        if np.linalg.norm(f[free]) < 1e-10 * law.E:
            break
        du = np.linalg.solve(K[np.ix_(free, free)], -f[free])
        u.ravel()[free] += du
    else:
        raise AssertionError("Newton did not converge")
    reaction = f.reshape(-1, 3)[pulled, 0].sum()  # total force on x = 1 (area 1)
    return p, u, reaction


@pytest.mark.parametrize("law", LAW_CLASSES)
@pytest.mark.parametrize("stretch", [0.85, 1.25])
def test_homogeneous_cube_matches_closed_form(law, stretch):
    m = law(E=3000.0, nu=0.45)
    s, S11 = _closed_form_uniaxial(m, stretch)
    p, u, reaction = _uniaxial_cube(m, stretch)
    # the P1 solution is exactly homogeneous: x_lateral = s X_lateral
    np.testing.assert_allclose(u[:, 1], (s - 1) * p[:, 1], atol=1e-10)
    np.testing.assert_allclose(u[:, 2], (s - 1) * p[:, 2], atol=1e-10)
    # nominal force on the unit face: P11 = stretch * S11
    assert reaction == pytest.approx(stretch * S11, rel=1e-8)


@pytest.mark.parametrize("law", LAW_CLASSES)
def test_small_strain_limit_is_linear_elasticity(law):
    m = law(E=1.0, nu=0.45)
    rng = np.random.default_rng(7)
    direction = rng.normal(size=(6, 3, 3))
    errors = []
    for h in (1e-2, 1e-3):
        H = h * direction
        eps = 0.5 * (H + H.transpose(0, 2, 1))
        sigma = 2 * m.mu * eps + m.lam * np.trace(eps, axis1=1, axis2=2)[
            :, None, None
        ] * np.eye(3)
        S = m.stress(np.eye(3) + H)
        errors.append(abs(S - sigma).max() / abs(sigma).max())
    assert errors[1] < 1e-2
    assert errors[0] / errors[1] == pytest.approx(10, rel=0.1)  # error O(h^2)
    np.testing.assert_allclose(
        m.tangent(np.eye(3)[None]), Svk(E=1.0, nu=0.45).tangent(np.eye(3)[None]),
        atol=1e-12,
    )  # fmt: skip


def test_neo_hookean_and_svk_agree_to_first_order():
    nh, svk = NeoHookean(E=5000.0, nu=0.45), Svk(E=5000.0, nu=0.45)
    rng = np.random.default_rng(8)
    direction = rng.normal(size=(6, 3, 3))
    rel = []
    for h in (2e-2, 1e-2, 5e-3):
        F = np.eye(3) + h * direction
        rel.append(abs(nh.stress(F) - svk.stress(F)).max() / abs(svk.stress(F)).max())
    # the relative difference is O(strain): halves with the strain
    assert rel[0] / rel[1] == pytest.approx(2, rel=0.1)
    assert rel[1] / rel[2] == pytest.approx(2, rel=0.1)
    assert rel[2] < 0.2  # and is not zero: they are different laws
    assert rel[2] > 1e-3
    # same on the cube: the axial force differs by O(strain)
    d = [
        abs(
            _closed_form_uniaxial(nh, 1 + e)[1] / _closed_form_uniaxial(svk, 1 + e)[1]
            - 1
        )
        for e in (1e-2, 5e-3)
    ]
    assert d[0] / d[1] == pytest.approx(2, rel=0.1)


@pytest.mark.parametrize("law", LAW_CLASSES)
def test_linear_in_modulus(law):
    F = _random_F(4, 0.1, seed=9)
    a, b = law(E=1.0, nu=0.45), law(E=2500.0, nu=0.45)
    assert law.linear_in_modulus
    np.testing.assert_allclose(b.energy(F), 2500 * a.energy(F), rtol=1e-12)
    np.testing.assert_allclose(b.stress(F), 2500 * a.stress(F), rtol=1e-12)
    np.testing.assert_allclose(b.tangent(F), 2500 * a.tangent(F), rtol=1e-12)


def test_neo_hookean_is_nan_for_inverted_elements():
    F = np.diag([1.0, 1.0, -1.0])[None]
    assert np.isnan(NeoHookean().stress(F)).all()
    assert np.isfinite(Svk().stress(F)).all()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (("rubber",), "material 'rubber': allowed are svk, neo-hookean"),
        (("svk", -1.0), "E = -1.0"),
        (("neo-hookean", 1.0, 0.5), "nu = 0.5"),
    ],
)
def test_make_material_rejects_bad_input(args, match):
    with pytest.raises(ValueError, match=match):
        make_material(*args)
    assert set(LAWS) == {"svk", "neo-hookean"}
