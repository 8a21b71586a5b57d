"""The ``solid`` model: equal to svk-beam on the beam, closed forms, FD, bad input."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from support.bodies import write_beam_body
from support.oracles import general_law

import idbench
from idbench.registry.testing import check_model
from idbench_fem.bodies import description as bodies
from idbench_fem.bodies.box import parse as beam_mesh
from idbench_fem.fem.law_assembly import LawAssembler
from idbench_fem.fem.materials import NeoHookean
from idbench_fem.models.beam import make_model as make_beam
from idbench_fem.models.beam_settings import end_traction
from idbench_fem.models.solid import SolidModel, make_model


def solid(body, mesh="truth", manipulation="end", steps=4, markers=2, **settings):
    scenario = idbench.Scenario(
        manipulation, {"body": str(body), "manipulation": manipulation}
    )
    return make_model(idbench.ModelSpec(mesh, scenario, steps, markers, settings))


def run(model, theta, steps=None):
    u = model.reset()
    for k in range(1, (steps or model.n_steps) + 1):
        u = model.step(np.atleast_1d(theta), k, u)
    return u


@pytest.mark.parametrize("kernel", ["auto", "general"])
def test_solid_on_the_beam_equals_svk_beam(tmp_path, kernel):
    body, _ = write_beam_body(tmp_path)
    s = solid(body, kernel=kernel)
    b = make_beam(idbench.ModelSpec(
        "8x2x2", end_traction("end", (0, -1, 0), 8.9), 4, 2, {"grid": (6, 3, 3)}
    ))  # fmt: skip
    assert s.n_state == b.n_state
    np.testing.assert_allclose(s.external_force(4), b.external_force(4), rtol=1e-12)
    us, ub = run(s, 5000.0), run(b, 5000.0)
    assert np.abs(us).max() > 1e-3  # a large deformation, not a trivial one
    # equal to the Newton tolerance: the solid's steps along a path reuse the
    # previous step's factorization (chords from a secant prediction)
    np.testing.assert_allclose(us, ub, rtol=0, atol=1e-8 * np.abs(ub).max())
    np.testing.assert_allclose(s.observe(us), b.observe(ub), rtol=1e-8)
    Js = s.sensitivity(np.array([5000.0]), 4, us)
    Jb = b.sensitivity(np.array([5000.0]), 4, ub)
    np.testing.assert_allclose(Js, Jb, rtol=1e-8)


def test_general_kernel_matches_the_reference_kernel():
    beam = beam_mesh("3x1x1")
    rng = np.random.default_rng(0)
    u = 0.01 * rng.standard_normal((len(beam.points), 3))
    free = np.ones(len(beam.points), dtype=bool)
    law = NeoHookean(E=1.0, nu=0.4)
    asm = LawAssembler(beam.points, beam.tets, free, law)
    modulus = rng.uniform(1.0, 3.0, len(beam.tets))
    kin = asm.kinematics(u.ravel(), modulus)
    grads, vol = general_law.shape_gradients(beam.points, beam.tets)
    fe, Ke = general_law.element_kernel(law, u, beam.tets, grads, vol, modulus)
    f_ref = np.bincount((3 * beam.tets[:, :, None] + np.arange(3)).ravel(),
                        fe.ravel(), u.size)  # fmt: skip
    np.testing.assert_allclose(asm.forces(kin), f_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(asm.element_tangents(kin, modulus), Ke, rtol=1e-10,
                               atol=1e-12 * np.abs(Ke).max())  # fmt: skip
    # and the tangent is the derivative of the force (central differences)
    pat = asm.pattern(upper=False)
    K = pat.matrix(asm.tangent_data(kin, modulus, pat)).toarray()
    h = 1e-7
    for j in (0, 7, 20):
        e = np.zeros(u.size)
        e[j] = h
        fp = asm.forces(asm.kinematics(u.ravel() + e, modulus))
        fm = asm.forces(asm.kinematics(u.ravel() - e, modulus))
        np.testing.assert_allclose((fp - fm) / (2 * h), K[:, j], rtol=1e-5,
                                   atol=1e-6 * np.abs(K).max())  # fmt: skip


@pytest.mark.parametrize("law", ["svk", "neo-hookean"])
def test_homogeneous_stretch_of_a_cube_closed_form(tmp_path, law):
    """nu = 0: uniaxial dead traction t on x = 1 of a unit cube fixed on x = 0.

    F = diag(s, 1, 1) is exact (P1 reproduces it): SVK P_xx = mu s (s^2 - 1),
    neo-Hookean P_xx = mu (s - 1/s); lateral stresses are zero for both.
    """
    beam = beam_mesh("3x3x3")
    pts = (beam.points - beam.lower) / (beam.upper - beam.lower)  # unit cube
    mesh_path = tmp_path / "cube.vtu"
    meshio.write(mesh_path, meshio.Mesh(pts, [("tetra", beam.tets)]))
    E, t = 1000.0, 300.0
    body = tmp_path / "cube.toml"
    body.write_text(f"""
[mesh]
truth = "cube.vtu"
[material]
law = "{law}"
E = {E}
nu = 0.0
[fixed]
half_space = {{ point = [1e-9, 0, 0], normal = [-1, 0, 0] }}
[[manipulation]]
name = "pull"
kind = "traction"
region = {{ half_space = {{ point = [0.999999, 0, 0], normal = [1, 0, 0] }} }}
traction = [{t}, 0.0, 0.0]
[markers]
points = [[1.0, 0.5, 0.5]]
""")
    model = solid(body, manipulation="pull", steps=3, markers=1)
    u = model.displacement_field(run(model, E))
    mu = E / 2
    from scipy.optimize import brentq

    p = (lambda s: mu * s * (s * s - 1)) if law == "svk" else (
        lambda s: mu * (s - 1 / s))  # fmt: skip
    s = brentq(lambda s: p(s) - t, 1.0, 3.0)
    assert s > 1.2  # large strain
    np.testing.assert_allclose(u[:, 0], (s - 1) * pts[:, 0], atol=1e-9)
    np.testing.assert_allclose(u[:, 1:], 0.0, atol=1e-9)


def test_neo_hookean_equals_svk_to_first_order_in_strain(tmp_path):
    diffs = []
    for scale in (1e-2, 1e-3):
        out = []
        for law in ("svk", "neo-hookean"):
            body, _ = write_beam_body(tmp_path, law=law,
                                      traction=(250.0 * scale, 0.0, 0.0))  # fmt: skip
            out.append(run(solid(body, steps=1, kernel="general"), 5000.0))
        svk, nh = out
        strain = np.abs(svk).max() / 0.2
        diffs.append(np.abs(nh - svk).max() / np.abs(svk).max() / strain)
    # relative difference O(strain): the same multiple of the strain at both loads
    assert 0.05 < diffs[0] < 5 and 0.5 < diffs[0] / diffs[1] < 2, diffs


@pytest.mark.parametrize("law", ["svk", "neo-hookean"])
def test_sensitivity_against_finite_differences_on_the_beam(tmp_path, law):
    body, _ = write_beam_body(tmp_path, spec="6x2x2", law=law)
    check_model(solid(body, steps=3), np.array([5000.0]), steps=2, fd_rtol=1e-5)


@pytest.fixture(scope="module")
def liver200():
    pytest.importorskip("gmsh")
    return dict(mesh="200", settings={"reference": "200"})


def test_liver_runs_and_identifies_nothing_wrong(liver200):
    sc = idbench.Scenario("grasp-lift", {"body": "liver", "manipulation": "grasp-lift"})
    model = make_model(idbench.ModelSpec("200", sc, 4, 3, liver200["settings"]))
    assert isinstance(model, SolidModel) and model.parameters.names == ("E",)
    assert model.parameters.default == (4000.0,)
    check_model(model, np.array([4000.0]), steps=2, fd_rtol=1e-5)
    u = run(model, 4000.0)
    up = model.observe(u)
    # lifting: the grasped edge goes up (+z), markers move by millimetres
    assert 1e-4 < np.abs(up).max() < 0.05


def test_kidney_identifies_one_modulus_per_region():
    pytest.importorskip("gmsh")
    sc = idbench.Scenario("sag", {"body": "kidney", "manipulation": "sag"})
    model = make_model(idbench.ModelSpec("200", sc, 2, 4, {"reference": "200"}))
    assert model.parameters.names == ("E_parenchyma", "E_inclusion")
    assert model.parameters.default == (6000.0, 24000.0)
    J = model.sensitivity(
        np.array([6000.0, 24000.0]),
        1,
        model.step(np.array([6000.0, 24000.0]), 1, model.reset()),
    )
    assert J.shape == (12, 2) and np.all(np.abs(J).max(axis=0) > 0)


# -- bad input: one line naming the bad value -----------------------------------


def one_line(exc):
    text = str(exc.value)
    assert "\n" not in text
    return text


def test_unknown_manipulation(tmp_path):
    body, _ = write_beam_body(tmp_path)
    with pytest.raises(ValueError) as exc:
        solid(body, manipulation="twist")
    assert "'twist'" in one_line(exc) and "end, pull" in one_line(exc)


def test_scenario_without_a_manipulation(tmp_path):
    sc = idbench.Scenario("bend-y", {"direction": [0, -1, 0], "magnitude": 8.9})
    with pytest.raises(ValueError) as exc:
        make_model(idbench.ModelSpec("200", sc))
    assert "'manipulation'" in one_line(exc)


def test_markers_outside_the_body(tmp_path):
    body, _ = write_beam_body(tmp_path, markers=[[0.1, 0.5, 0.015]])
    with pytest.raises(ValueError) as exc:
        solid(body, markers=1)
    assert "[markers] point 1" in one_line(exc) and "outside" in one_line(exc)


def test_more_markers_than_the_body_has(tmp_path):
    body, _ = write_beam_body(tmp_path)
    with pytest.raises(ValueError) as exc:
        solid(body, markers=5)
    assert "5 markers" in one_line(exc)


def test_unknown_mesh_and_body(tmp_path):
    body, _ = write_beam_body(tmp_path)
    with pytest.raises(ValueError) as exc:
        solid(body, mesh="liver-n500")
    assert "'liver-n500'" in one_line(exc) and "beam-8x2x2" in one_line(exc)
    with pytest.raises(ValueError) as exc:
        solid(tmp_path / "nope.toml")
    assert "nope.toml" in one_line(exc) and "liver" in one_line(exc)


def test_transfer_must_name_another_manipulation(tmp_path):
    body, _ = write_beam_body(tmp_path)
    text = body.read_text().replace('name = "pull"', 'name = "pull"\ntransfer = "x"')
    with pytest.raises(ValueError) as exc:
        bodies.parse_body(__import__("tomllib").loads(text), "b.toml")
    assert "transfer = 'x'" in one_line(exc)


def test_bad_settings():
    from idbench_fem.models.solid_settings import SolidSettings

    for kw, word in (({"law": "rubber"}, "law"),
                     ({"kernel": "fast"}, "kernel"), ({"nu": 0.5}, "nu"),
                     ({"load_scale": 0.0}, "load_scale")):  # fmt: skip
        with pytest.raises(ValueError, match=word):
            SolidSettings(**kw)


def test_scenarios_of_the_shipped_bodies_and_env(tmp_path, monkeypatch):
    body, _ = write_beam_body(tmp_path)
    text = (
        body.read_text().replace('"end"', '"own-end"').replace('"pull"', '"own-pull"')
    )
    body.write_text(text)
    monkeypatch.setenv("IDBENCH_BODIES", str(body))
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    for name, transfer in (("grasp-lift", "lateral-push"), ("sag-90", "grasp-lift"),
                           ("own-end", "own-pull")):  # fmt: skip
        assert reg.scenario(name).transfer == transfer
    assert reg.scenario("own-end").load == {
        "body": str(body),
        "manipulation": "own-end",
    }
    assert reg.scenario("grasp-pole").load["body"] == "kidney"


def test_simulate_writes_the_liver_with_region_tags(tmp_path, capsys):
    pytest.importorskip("gmsh")
    from idbench.cli.commands import main

    out = tmp_path / "liver.xdmf"
    code = main(["simulate", "--model", "solid", "--mesh", "200", "--scenario",
                 "grasp-lift", "--model-option", "reference=200", "--steps", "2",
                 "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    assert "u_max" in capsys.readouterr().out
    with meshio.xdmf.TimeSeriesReader(out) as reader:
        reader.read_points_cells()
        _t, point_data, cell_data = reader.read_data(1)
    assert np.abs(point_data["displacement"]).max() > 1e-4
    assert set(cell_data) == {"region", "E_factor"}


def test_load_scale_scales_the_external_force(tmp_path):
    body, _ = write_beam_body(tmp_path)
    full, third = solid(body), solid(body, load_scale=1 / 3)
    np.testing.assert_allclose(3 * third.external_force(2), full.external_force(2))
    assert third.describe()["load_scale"] == 1 / 3


def test_describe_keys_on_contents_not_on_folders(tmp_path):
    import shutil

    body, _ = write_beam_body(tmp_path)
    other = tmp_path / "moved"
    other.mkdir()
    for f in (body, tmp_path / "beam-8x2x2.vtu"):
        shutil.copy(f, other / f.name)
    a, b = solid(body).describe(), solid(other / body.name).describe()
    assert a == b and a["mesh_sha256"] and str(tmp_path) not in str(a)
    assert solid(body, nu=0.3).describe() != a


def test_path_reuse_is_true_false_or_unset():
    from idbench_fem.models.solid_settings import SolidSettings

    assert SolidSettings(path_reuse=False).path_reuse is False
    assert SolidSettings().identity() == SolidSettings(path_reuse=None).identity()
    assert SolidSettings(path_reuse=True).identity() != SolidSettings().identity()
    with pytest.raises(ValueError, match="path_reuse 'yes': need true or false"):
        SolidSettings(path_reuse="yes")  # type: ignore[arg-type]
