"""Elastic supports: a block on springs against the exact solution, FD, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from support.helpers import write_box_mesh

import idbench
from idbench.registry.testing import check_batch_model, check_model
from idbench_fem.bodies.description import load_body
from idbench_fem.fem.hyper import HyperReduced
from idbench_fem.models.reduced import ReducedModel
from idbench_fem.models.reduction import (
    Reduction,
    ReductionSpec,
    element_dofs,
    element_factors,
    element_set,
    reduced_springs,
)
from idbench_fem.models.solid import make_model

W = 0.02  # m: a cube [0, W]^3
E, NU = 5000.0, 0.3
KB, KS = 4.0e5, 2.0e5  # N/m3: bottom, sides
P = 0.05  # Pa on the top face: small, so the nonlinear solution is ~ the linear

EPS = 1e-9
HALF = "{{ half_space = {{ point = {p}, normal = {n} }} }}"


def _face(axis: int, high: bool) -> str:
    point = [0.0, 0.0, 0.0]
    normal = [0.0, 0.0, 0.0]
    point[axis] = W - EPS if high else EPS
    normal[axis] = 1.0 if high else -1.0
    return HALF.format(p=point, n=normal)


def block_body(tmp_path, law="svk", identify="", k_t=0.0, fixed="", extra=""):
    """A cube on normal springs: bottom (z = 0) and the faces x = 0, y = 0."""
    write_box_mesh(tmp_path / "cube.vtu", 4, W, W, n_yz=4)
    ident = f'identify = ["k_n"]\nprior = {{ k_n = [{KB / 2}, {KB / 2}] }}'
    text = f"""
[mesh]
truth = "cube.vtu"
[material]
law = "{law}"
E = {E}
nu = {NU}
{fixed}
[[support]]
name = "bottom"
region = {_face(2, False)}
k_n = {KB}
k_t = {k_t}
{ident if identify else ""}
[[support]]
name = "xside"
region = {_face(0, False)}
k_n = {KS}
[[support]]
name = "yside"
region = {_face(1, False)}
k_n = {KS}
[[manipulation]]
name = "press"
kind = "pressure"
region = {_face(2, True)}
pressure = {P}
[markers]
points = [[{W}, {W}, {W}], [0.0, 0.0, {W}], [{W}, 0.0, 0.0]]
[shape_error]
grid = [2, 2, 2]
{extra}
"""
    path = tmp_path / f"cube-{law}{identify}.toml"
    path.write_text(text)
    return path


def model_of(body, steps=2, markers=3, **settings):
    scenario = idbench.Scenario("press", {"body": str(body), "manipulation": "press"})
    spec = idbench.ModelSpec("truth", scenario, steps, markers, {"body": str(body)})
    if settings:
        spec = idbench.ModelSpec(
            "truth", scenario, steps, markers, {"body": str(body), **settings}
        )
    return make_model(spec)


def exact(points):
    """Uniaxial stress sigma_zz = -P; the faces x = 0, y = 0 do not move normally."""
    x, y, z = points.T
    return np.stack([NU * P * x / E, NU * P * y / E, -P / KB - P * z / E], axis=1)


@pytest.mark.parametrize("law", ["svk", "neo-hookean"])
def test_block_on_springs_is_the_exact_linear_solution(tmp_path, law):
    model = model_of(block_body(tmp_path, law))
    assert model.parameters.names == ("E",)
    assert len(model.fixed_nodes) == 0  # held by springs only
    theta = np.array([E])
    K0 = model.tangent(theta, model.reset()).toarray()
    u_lin = np.linalg.solve(K0, model.external_force(model.n_steps))
    want = exact(model.mesh()[0])
    np.testing.assert_allclose(
        u_lin.reshape(-1, 3), want, rtol=0, atol=1e-10 * np.abs(want).max()
    )
    # the nonlinear path ends there to O(strain) (P / E = 1e-5)
    u = model.reset()
    for k in range(1, model.n_steps + 1):
        u = model.step(theta, k, u)
    np.testing.assert_allclose(
        u.reshape(-1, 3), want, rtol=0, atol=1e-4 * np.abs(want).max()
    )
    # the tangent is the derivative of the internal force, springs included
    rng = np.random.default_rng(0)
    v = 1e-4 * rng.standard_normal(model.n_state)
    h = 1e-7
    fd = (
        model.internal_force(theta, u + h * v) - model.internal_force(theta, u - h * v)
    ) / (2 * h)
    Kv = model.tangent(theta, u) @ v
    np.testing.assert_allclose(Kv, fd, rtol=1e-6, atol=1e-8 * np.abs(Kv).max())


def test_a_stiff_block_settles_by_p_over_k(tmp_path):
    model = model_of(block_body(tmp_path))
    theta = np.array([1e4 * E])  # a nearly rigid block
    u = model.reset()
    for k in range(1, model.n_steps + 1):
        u = model.step(theta, k, u)
    settle = u.reshape(-1, 3)[:, 2]
    np.testing.assert_allclose(settle, -P / KB, rtol=1e-3)


@pytest.mark.parametrize("law", ["svk", "neo-hookean"])
def test_an_identified_stiffness_is_a_parameter_with_its_sensitivity(tmp_path, law):
    model = model_of(block_body(tmp_path, law, identify="k_n"), markers=3)
    spec = model.parameters
    assert spec.names == ("E", "k_n_bottom")
    assert spec.default == (E, KB)
    assert spec.priors == (("k_n_bottom", KB / 2, KB / 2),)
    assert spec.lower[1] == pytest.approx(1e-3 * KB)
    prior = spec.prior(2500.0, 2500.0)
    assert prior.mean == (2500.0, KB / 2) and prior.std == (2500.0, KB / 2)
    theta = np.array([0.8 * E, 1.3 * KB])
    check_model(model, theta, steps=2)
    u = model.reset()
    for k in (1, 2):
        u = model.step(theta, k, u)
    J = model.sensitivity(theta, 2, u)
    for j in range(2):  # per column: the units differ
        h = 1e-6 * theta[j]
        up, dn = theta.copy(), theta.copy()
        up[j] += h
        dn[j] -= h
        run = []
        for t in (up, dn):
            x = model.reset()
            for k in (1, 2):
                x = model.step(t, k, x)
            run.append(model.observe(x))
        fd = (run[0] - run[1]) / (2 * h)
        np.testing.assert_allclose(J[:, j], fd, rtol=0, atol=1e-4 * np.abs(fd).max())
    assert np.abs(J[:, 1]).max() > 0


def test_sigma_points_of_springs_equal_single_steps(tmp_path):
    model = model_of(block_body(tmp_path, identify="k_n", k_t=1e4))
    thetas = np.array([[E, KB], [0.7 * E, KB], [E, 1.5 * KB], [1.3 * E, 0.6 * KB]])
    check_batch_model(model, thetas)


def test_springs_that_leave_a_rigid_motion_are_refused(tmp_path):
    body = block_body(tmp_path)
    text = body.read_text()
    # drop the side supports: normal springs under the bottom alone let it slide
    cut = text.index('[[support]]\nname = "xside"')
    end = text.index("[[manipulation]]")
    body.write_text(text[:cut] + text[end:])
    with pytest.raises(ValueError, match="rigid motion"):
        model_of(body)
    # with tangential springs on the bottom it is held
    body.write_text(body.read_text().replace("k_t = 0.0", "k_t = 1000.0"))
    assert model_of(body).parameters.p == 1


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ("k_n = 400000.0\n", ["needs region", "k_n"]),
        (
            "k_t = 0.0",
            ["k_t = -1", ">= 0"],
        ),
    ],
)
def test_bad_supports_get_one_line(tmp_path, change, words):
    body = block_body(tmp_path)
    text = body.read_text()
    if change.startswith("k_n"):
        text = text.replace(change, "", 1)
    else:
        text = text.replace(change, "k_t = -1.0", 1)
    body.write_text(text)
    with pytest.raises(ValueError) as err:
        load_body(body)
    msg = str(err.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_identify_without_a_prior_is_refused(tmp_path):
    body = block_body(tmp_path, identify="k_n")
    text = body.read_text().replace("prior = { k_n = [200000.0, 200000.0] }", "")
    body.write_text(text)
    with pytest.raises(ValueError, match=r"no prior\.k_n"):
        load_body(body)


def test_springs_on_a_clamped_face_do_nothing(tmp_path):
    clamp = (
        "[fixed]\nhalf_space = { point = [0.0, 0.0, 1e-9], normal = [0.0, 0.0, -1.0] }"
    )
    body = block_body(tmp_path, fixed=clamp)
    assert load_body(body).fixed is not None
    model = model_of(body)
    assert len(model.fixed_nodes) == 16
    K = model.tangent(np.array([E]), model.reset())
    # the bottom's springs lie on fixed nodes; the sides' hold the rest
    assert K.shape == (model.n_state, model.n_state)


def test_the_body_check_resolves_the_supports(tmp_path):
    from idbench_fem.bodies import resolve

    body = block_body(tmp_path)
    resolve.check(load_body(body))
    far = "{ sphere = { centre = [1.0, 1.0, 1.0], radius = 0.001 } }"
    text = body.read_text().replace(_face(0, False), far, 1)
    body.write_text(text)
    with pytest.raises(ValueError, match="support") as err:
        resolve.check(load_body(body))
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("law", ["svk", "neo-hookean"])
def test_a_reduction_with_every_mode_and_element_keeps_the_springs(tmp_path, law):
    """Springs in a reduced model: exact when nothing is left out (V = I)."""
    full = model_of(block_body(tmp_path, law, identify="k_n"), steps=3)
    n, T = full.n_state, len(full.mesh()[1])
    whole = Reduction("all", np.eye(n), np.ones(n), np.arange(T), np.ones(T), {})
    rom = ReducedModel(full, whole, ReductionSpec("truth"))
    rom.rtol = full.rtol
    theta = np.array([0.7 * E, 1.6 * KB])  # an identified and two known springs
    U, Q = [full.reset()], [rom.reset()]
    for k in (1, 2, 3):
        U.append(full.step(theta, k, U[-1]))
        Q.append(rom.step(theta, k, Q[-1]))
    scale = np.abs(U[-1]).max()
    assert scale > 0
    np.testing.assert_allclose(Q[-1], U[-1], rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(
        rom.sensitivity(theta, 3, Q[-1]), full.sensitivity(theta, 3, U[-1]),
        rtol=1e-6, atol=1e-9 * np.abs(full.sensitivity(theta, 3, U[-1])).max(),
    )  # fmt: skip
    assert rom.parameters.names == ("E", "k_n_bottom")
    assert rom.diagnostics()["reduction_residual"] < 1e-6  # the fine residual


def test_a_sampled_reduction_of_springs_has_its_derivative(tmp_path):
    """The hyper-reduced force with springs: its tangent is its derivative."""
    full = model_of(block_body(tmp_path, "neo-hookean", identify="k_n"), steps=2)
    _, tets = full.mesh()
    rng = np.random.default_rng(4)
    V = np.linalg.qr(rng.standard_normal((full.n_state, 5)))[0]
    pick = np.sort(rng.choice(len(tets), 12, replace=False))
    hyper = HyperReduced(
        element_set(full, tets[pick]), element_dofs(full, tets[pick]), V,
        rng.uniform(0.5, 2.0, len(pick)), element_factors(full)[pick],
        full.element_regions[pick], full.parameters.p,
        springs=reduced_springs(full, V),
    )  # fmt: skip
    theta = np.array([E, KB])
    q = 1e-6 * rng.standard_normal(5)
    K = hyper.tangent(hyper.evaluate(q), theta)
    for j in range(5):
        dq = np.zeros(5)
        dq[j] = 1e-9
        fd = (hyper.force(hyper.evaluate(q + dq), theta)
              - hyper.force(hyper.evaluate(q - dq), theta)) / 2e-9  # fmt: skip
        np.testing.assert_allclose(K[:, j], fd, rtol=1e-5, atol=1e-6 * abs(K).max())
    springs_only = hyper.force(hyper.evaluate(q), np.array([0.0, KB]))
    S = reduced_springs(full, V)
    assert S is not None
    exact = KB * S.matrices[S.index >= 0].sum(axis=0) @ q + S.constant @ q
    np.testing.assert_allclose(springs_only, exact, rtol=1e-12)


def test_a_design_ranges_the_identified_stiffnesses_too(tmp_path):
    """[design] moduli: E for every modulus, each identified stiffness its own."""
    extra = (
        "[design]\nmanipulations = [\"press\"]\nsteps = 3\npaths = 2\n"
        f"moduli = {{ E = [1000.0, 8000.0], k_n_bottom = [{KB / 4}, {4 * KB}], "
        f"k_n_xside = [{KS / 2}, {2 * KS}] }}\n"
    )
    identified = load_body(block_body(tmp_path, identify="k_n", extra=extra))
    assert identified.design is not None
    assert [m[0] for m in identified.design.moduli] == ["E", "k_n_bottom"]
    assert identified.design.thetas().shape == (2, 2)  # (a known range unused)
    with pytest.raises(ValueError, match="for each parameter: E, k_n_bottom"):
        load_body(block_body(tmp_path, identify="k_n", extra=extra.replace(
            f"k_n_bottom = [{KB / 4}, {4 * KB}], ", "")))  # fmt: skip
