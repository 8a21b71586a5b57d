"""The SVK beam forward model: physics checks, Newton, sensitivities, protocol."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.beams import beam_model
from support.oracles import svk_forms

import idbench
from idbench_fem.bodies import box
from idbench_fem.fem.solver import pardiso_available, resolve_backend
from idbench_fem.models.beam import make_model
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_fem.models.beam_settings import end_traction

BEND_Y, BEND_Z, STRETCH_X, MIXED_30, MIXED_60 = SCENARIOS
E_TRUE = np.array([5000.0])


def _run(model, theta, n=None, substeps=1):
    u = model.reset()
    for k in range(1, (n or model.n_steps) + 1):
        u = model.step(theta, k, u, substeps=substeps)
    return u


def _tiny(direction=(0.0, -1.0, 0.0), magnitude=1e-4):
    return end_traction("tiny", direction, magnitude)


# -- physics -------------------------------------------------------------------


def test_small_load_limit_is_linear_elasticity():
    m = beam_model(box.parse("10x2x2"), _tiny((0.6, -0.8, 0.0)), n_steps=1, nu=0.45)
    u = m.displacement_field(m.step(E_TRUE, 1, m.reset()))
    f = np.zeros(3 * m.n_nodes)  # the end traction (none needed on the clamp)
    f[m._asm.free_dofs] = m.external_force(1)
    f = f.reshape(-1, 3)
    end = m.mesh_data.points[:, 0] == 0.2
    total = 1e-4 * 0.03**2 * np.array([0.6, -0.8, 0])
    np.testing.assert_allclose(f[end].sum(axis=0), total)
    u_lin = svk_forms.linear_solution(
        m.mesh_data.points, m.mesh_data.tets, m.fixed_nodes, f, 5000.0, 0.45
    )
    np.testing.assert_allclose(u, u_lin, rtol=0, atol=1e-5 * np.abs(u_lin).max())


def test_tip_deflection_matches_timoshenko():
    # P1 tets converge slowly in bending: extrapolate three meshes (h ratio 1.5,
    # same element shape) with Aitken's delta-squared, nu = 0.3 (no locking)
    E, nu, t = 5000.0, 0.3, 1e-3
    L, W, H = 0.2, 0.03, 0.03
    force, inertia, shear = t * W * H, W * H**3 / 12, E / (2 * (1 + nu))
    kappa = 10 * (1 + nu) / (12 + 11 * nu)
    timoshenko = force * L**3 / (3 * E * inertia) + force * L / (kappa * shear * W * H)
    d = []
    for n in [(20, 4, 4), (30, 6, 6), (45, 9, 9)]:
        m = beam_model(box.structured(*n), _tiny(magnitude=t), n_steps=1, nu=nu)
        d.append(-m.probe("tip", m.step(np.array([E]), 1, m.reset()))[1])
    d1, d2, d3 = d
    assert d1 < d2 < d3 < timoshenko  # stiff from below
    extrapolated = d3 - (d3 - d2) ** 2 / ((d3 - d2) - (d2 - d1))
    assert extrapolated == pytest.approx(timoshenko, rel=0.03)


def test_discretization_stiffening():
    tips = []
    for spec in ("240", "4000"):
        m = make_model(idbench.ModelSpec(mesh=spec, scenario=BEND_Y, n_steps=2))
        tips.append(-m.probe("tip", _run(m, E_TRUE))[1])
    assert tips[0] < 0.85 * tips[1]
    assert 0.03 < tips[1] < 0.08  # about a quarter of the length, as designed


# -- Newton --------------------------------------------------------------------


def test_newton_converges_quadratically():
    m = beam_model(
        box.parse("14x3x3"),
        STRETCH_X,
        n_steps=1,
        options={"rtol": 1e-12, "atol": 1e-300, "chord_ratio": 0.0},  # plain Newton
    )
    m.step(E_TRUE, 1, m.reset())
    r = np.array(m.last_residuals)
    assert len(r) <= 8
    # r_{i+1} <= C r_i^2 (normalised by r_0) while above round-off
    tail = [i for i in range(1, len(r) - 1) if r[i + 1] > 1e-13 * r[0]]
    assert len(tail) >= 2
    assert all(r[i + 1] * r[0] / r[i] ** 2 < 50 for i in tail), r
    assert r[-1] <= 1e-12 * r[0]


def test_twenty_steps_bitwise_deterministic():
    runs = []
    for _ in range(2):
        m = make_model(idbench.ModelSpec(mesh="500", scenario=MIXED_30, n_steps=20))
        us = [m.reset()]
        for k in range(1, 21):
            us.append(m.step(E_TRUE, k, us[-1]))
        runs.append(np.array(us))
    assert runs[0].tobytes() == runs[1].tobytes()
    # and the same model recomputing a step from the same inputs
    assert m.step(E_TRUE, 7, runs[0][6]).tobytes() == runs[0][7].tobytes()


def test_step_is_stateless_and_counts_cost():
    m = beam_model(box.parse("8x2x2"), BEND_Z, n_steps=4)
    u0 = m.reset()
    assert u0.shape == (m.n_state,) and not u0.any()
    u1 = m.step(E_TRUE, 1, u0)
    copy = u1.copy()
    u2a = m.step(E_TRUE, 2, u1)
    m.step(2 * E_TRUE, 2, u1)  # another sigma point in between
    u2b = m.step(E_TRUE, 2, u1)
    assert np.array_equal(u1, copy) and np.array_equal(u2a, u2b)
    c = m.cost()
    assert c.forward_solves == 4
    assert c.newton_its >= 4 and c.linear_solves == c.newton_its


def test_substeps_reach_the_same_state():
    m = beam_model(box.parse("8x2x2"), BEND_Y, n_steps=2)
    a = _run(m, E_TRUE)
    b = _run(m, E_TRUE, substeps=3)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(a).max())


def test_model_failure_on_absurd_parameters():
    m = beam_model(box.parse("8x2x2"), BEND_Y, n_steps=1)
    with pytest.raises(idbench.ModelFailure) as info:
        m.step(np.array([1e-3]), 1, m.reset())
    assert info.value.step == 1
    with pytest.raises(idbench.ModelFailure):
        m.step(np.array([np.nan]), 1, m.reset())
    with pytest.raises(idbench.ModelFailure):
        m.step(np.array([-5.0]), 1, m.reset())


def test_substeps_rescue_a_large_step():
    m = beam_model(box.parse("8x2x2"), BEND_Y, n_steps=1, options={"max_iterations": 5})
    with pytest.raises(idbench.ModelFailure):
        m.step(np.array([1500.0]), 1, m.reset())
    u = m.step(np.array([1500.0]), 1, m.reset(), substeps=8)
    assert np.all(np.isfinite(u))


def test_bad_arguments():
    m = beam_model(box.parse("4x2x2"), BEND_Y, n_steps=3)
    with pytest.raises(ValueError, match="k = 4"):
        m.step(E_TRUE, 4, m.reset())
    with pytest.raises(ValueError, match="shape"):
        m.step(E_TRUE, 1, np.zeros(5))
    with pytest.raises(ValueError, match="theta"):
        m.step(np.array([1.0, 2.0]), 1, m.reset())
    with pytest.raises(ValueError, match="'Q'"):
        make_model(
            idbench.ModelSpec(
                mesh="4x2x2", scenario=BEND_Y, settings={"parameters": "Q"}
            )
        )


# -- sensitivities ---------------------------------------------------------------


@pytest.mark.parametrize(
    "options",
    [
        {"regions": 2},
        {"regions": 3},
        {"inclusion": (0.1, 0.2, 0, 0.03, 0, 0.03)},
        {"inclusion": (0.05, 0.15, 0, 0.015, 0, 0.03), "regions": 2},
    ],
)
def test_sensitivity_matches_finite_differences(options):
    m = beam_model(
        box.parse("12x2x2"),
        MIXED_60,
        n_steps=3,
        markers=5,
        parameters="E_regions",
        options=options,
    )
    p = m.parameters.p
    theta = np.linspace(4000.0, 6000.0, p)
    u = _run(m, theta)
    reused = m.sensitivity(theta, 3, u)  # the factorization of the last step
    before = m.cost()
    again = m.sensitivity(theta, 3, u.copy())
    assert (m.cost() - before).newton_its == 0
    other = m.step(theta * 1.1, 3, u)  # invalidates the cached factorization
    exact = m.sensitivity(theta, 3, u)
    assert reused.shape == (15, p)
    for j in range(p):
        h = 1e-6 * theta[j]
        e = np.zeros(p)
        e[j] = h
        fd = (m.observe(_run(m, theta + e)) - m.observe(_run(m, theta - e))) / (2 * h)
        scale = np.abs(fd).max()
        for s in (reused, again, exact):
            np.testing.assert_allclose(s[:, j], fd, rtol=0, atol=1e-6 * scale)
    assert np.all(np.isfinite(other))


@pytest.mark.parametrize("scenario", [STRETCH_X, MIXED_60])
def test_sensitivity_after_chord_steps_is_as_good_as_a_fresh_factorization(scenario):
    # stretching converges after one Newton update and chord steps: the
    # factorization held is then a whole load increment old, so sensitivity()
    # must factor K(u) itself rather than refine from it (a 2e-5 error before)
    m = beam_model(box.parse("12x3x3"), scenario, n_steps=3, markers=5)
    theta = E_TRUE
    u = _run(m, theta)
    reused = m.sensitivity(theta, 3, u)
    m.step(theta * 1.1, 3, u)  # something else factored: the next one is fresh
    exact = m.sensitivity(theta, 3, u)
    scale = np.abs(exact).max()
    np.testing.assert_allclose(reused, exact, rtol=0, atol=1e-7 * scale)


def test_chord_ratio_must_be_below_one():
    for bad in (-0.1, 1.0, 2.0):
        with pytest.raises(ValueError, match="chord_ratio"):
            beam_model(box.parse("4x1x1"), STRETCH_X, options={"chord_ratio": bad})


def test_inclusion_with_background_slabs():
    """The box is the last region; the rest is split into ``regions`` slabs."""
    cuboid = (0.08, 0.12, 0.0075, 0.0225, 0.0075, 0.0225)
    m = beam_model(
        box.parse("20x4x4"),
        BEND_Y,
        n_steps=1,
        parameters="E_regions",
        options={"inclusion": cuboid, "regions": 3},
    )
    assert m.parameters.names == tuple(f"E_region{r}" for r in range(4))
    c = m.mesh_data.points[m.mesh_data.tets].mean(axis=1)
    inside = np.all((c >= cuboid[0::2]) & (c <= cuboid[1::2]), axis=1)
    assert np.all(m.element_regions[inside] == 3)
    assert inside.sum() == 4 * 2 * 2 * 6  # the box is 4x2x2 hexes of this mesh
    slab = np.minimum((c[:, 0] / 0.2 * 3).astype(int), 2)
    np.testing.assert_array_equal(m.element_regions[~inside], slab[~inside])
    one = beam_model(
        box.parse("20x4x4"), BEND_Y, n_steps=1, parameters="E_regions",
        options={"inclusion": cuboid},
    )  # fmt: skip
    np.testing.assert_array_equal(one.element_regions, inside.astype(int))
    with pytest.raises(ValueError, match=r"slab \(0, 2\).*contains no tetrahedron"):
        beam_model(
            box.parse("4x1x1"), BEND_Y, n_steps=1, parameters="E_regions",
            options={"inclusion": (0.0, 0.1, 0, 0.03, 0, 0.03), "regions": 2},
        )  # fmt: skip


def test_single_modulus_sensitivity_is_minus_u_over_E_in_linear_limit():
    m = beam_model(box.parse("10x2x2"), _tiny(), n_steps=1, markers=2)
    u = m.step(E_TRUE, 1, m.reset())
    np.testing.assert_allclose(
        m.sensitivity(E_TRUE, 1, u)[:, 0], -m.observe(u) / 5000.0, rtol=1e-5, atol=1e-20
    )


# -- backends --------------------------------------------------------------------


@pytest.mark.skipif(not pardiso_available(), reason="pypardiso not installed")
def test_pardiso_and_scipy_agree(monkeypatch):
    states = {}
    for backend in ("pardiso", "scipy"):
        monkeypatch.setenv("IDBENCH_SOLVER", backend)
        m = beam_model(box.parse("14x3x3"), MIXED_30, n_steps=4, markers=4)
        assert m.backend == backend
        states[backend] = (_run(m, E_TRUE), m.sensitivity(E_TRUE, 4, _run(m, E_TRUE)))
    a, b = states["pardiso"], states["scipy"]
    np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-9 * np.abs(a[0]).max())
    np.testing.assert_allclose(a[1], b[1], rtol=0, atol=1e-7 * np.abs(a[1]).max())


def test_backend_selection(monkeypatch):
    monkeypatch.setenv("IDBENCH_SOLVER", "scipy")
    assert resolve_backend() == "scipy"
    assert resolve_backend("scipy") == "scipy"
    monkeypatch.setenv("IDBENCH_SOLVER", "umfpack")
    with pytest.raises(ValueError, match=r"'umfpack'.*pardiso, scipy"):
        resolve_backend()


# -- protocol extras ---------------------------------------------------------------


def test_observation_operators_and_description():
    spec = idbench.ModelSpec(
        mesh="14x3x3", scenario=BEND_Y, n_steps=3, markers=6,
        settings={"grid": (4, 4, 20)},
    )  # fmt: skip
    m = make_model(spec)
    u = _run(m, E_TRUE)
    assert m.marker_points.shape == (6, 3) and m.grid_points.shape == (320, 3)
    field = m.displacement_field(u)
    assert not field[m.fixed_nodes].any()
    pts, _ = m.mesh()
    corner = np.flatnonzero(np.all(np.isclose(pts, [0.2, 0.0, 0.03]), axis=1))[0]
    np.testing.assert_allclose(m.observe(u)[:3], field[corner], atol=1e-15)
    assert m.grid(u).shape == (320, 3)
    assert m.probe("tip", u)[1] < 0
    d = m.describe()
    assert json.loads(json.dumps(d)) == d
    assert d["n_nodes"] == 240 and d["n_steps"] == 3
    assert make_model(spec).describe() == d
    other = make_model(idbench.ModelSpec(mesh="14x3x4", scenario=BEND_Y, n_steps=3))
    assert other.describe()["mesh_sha256"] != d["mesh_sha256"]
