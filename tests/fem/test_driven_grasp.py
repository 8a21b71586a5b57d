"""A displacement-controlled grasp: the tool moves its patch, its force is observed.

Checked against what does not share its code: (a) its reaction applied as
nodal loads in a force-controlled solve gives back the prescribed
displacement; (b) the reaction is the derivative of the equilibrium strain
energy along the tool's path (finite differences); (c) with the force
observed, RO-UKF identifies E, and markers alone are refused in one line.
"""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from support.helpers import write_box_mesh

from idbench.cli.commands import main
from idbench.plan.config import CompareConfig, ConfigError
from idbench.run.compare import runs_of
from idbench_fem.bodies.description import parse_body
from idbench_fem.bodies.mesh import read_mesh
from idbench_fem.fem.materials import make_material
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid_settings import SolidSettings

L, W = 0.1, 0.02
D = (0.0, 0.0, -0.006)

GRASP = """[[manipulation]]
name = "{name}"
kind = "grasp"
point = [0.1, 0.01, 0.01]
radius = 0.015
{load}
"""
"""The end grasp, driven (``displacement``) or loaded (``force``)."""

BODY = """
[mesh]
truth = "box.vtu"
models = ["box.vtu"]

[material]
law = "{law}"
E = 5000.0
nu = 0.4
density = 1000.0

[fixed]
box = {{ lower = [-0.001, -1.0, -1.0], upper = [0.001, 1.0, 1.0] }}

{grasps}
[markers]
points = [[0.05, 0.0, 0.02], [0.07, 0.02, 0.02], [0.03, 0.01, 0.02]]
snap_distance = 0.002

[shape_error]
grid = [6, 2, 2]
"""


def body_text(law: str) -> str:
    """The box body TOML with the material ``law``."""
    grasps = GRASP.format(name="pull-end", load="displacement = [0.0, 0.0, -0.006]")
    grasps += "\n" + GRASP.format(name="push-end", load="force = [0.0, 0.0, -0.01]")
    return BODY.format(law=law, grasps=grasps)


@pytest.fixture
def box(tmp_path, monkeypatch):
    """A 6 x 2 x 2 box (63 nodes) clamped at x = 0; the body TOML's path."""
    monkeypatch.delenv("IDBENCH_BODIES", raising=False)
    write_box_mesh(tmp_path / "box.vtu", 7, L, W)
    path = tmp_path / "box.toml"
    path.write_text(body_text("neo-hookean"))
    return path


def _model(path, name="pull-end", steps=4, law="neo-hookean", **settings):
    raw = tomllib.loads(path.read_text().replace("neo-hookean", law))
    body = parse_body(raw, str(path), path.parent)
    mesh = read_mesh(path.parent / "box.vtu")
    s = SolidSettings(**settings)
    return SolidModel(body, mesh, name, mesh, steps, 3, s)


def _path(model, theta):
    u = model.reset()
    for k in range(1, model.n_steps + 1):
        u = model.step(theta, k, u)
    return u


@pytest.mark.parametrize("law", ["neo-hookean", "svk"])
def test_the_reaction_as_loads_gives_back_the_prescribed_displacement(box, law):
    theta = np.array([5000.0])
    driven = _model(box, law=law)
    u = _path(driven, theta)
    nodes = driven.driven_nodes
    assert len(nodes) > 3
    field = driven.displacement_field(u)
    np.testing.assert_array_equal(field[nodes], np.tile(D, (len(nodes), 1)))
    # the tool's nodal forces: the internal force at its nodes
    f = driven.internal_force(theta, u)
    f2f = driven._state_asm().full_to_free.reshape(-1, 3)
    nodal = f[f2f[nodes]]  # (D, 3)
    np.testing.assert_allclose(
        nodal.sum(axis=0), driven.reaction(theta, driven.n_steps, u), rtol=1e-12
    )
    # the same body loaded by those nodal forces (a force-controlled grasp
    # whose load is replaced by them), solved from rest
    loaded = _model(box, "push-end", steps=8, law=law)
    full = np.zeros((loaded.n_nodes, 3))
    full[nodes] = nodal
    loaded._f_end = full.ravel()[loaded._state_asm().free_dofs]
    loaded.atol = 1e-12 * float(np.linalg.norm(loaded._f_end))
    v = _path(loaded, theta)
    got = loaded.displacement_field(v)
    scale = float(np.abs(field).max())
    np.testing.assert_allclose(got[nodes], field[nodes], rtol=0, atol=1e-6 * scale)
    np.testing.assert_allclose(got, field, rtol=0, atol=1e-6 * scale)


def _energy(model, theta, u):
    """Strain energy of the state: sum of V_e E_e W_1(F_e)."""
    asm = model._state_asm()
    kin = asm.kinematics(u, model.element_moduli(theta, None))
    law = make_material(model.law_name, 1.0, model.nu)
    w = law.energy(np.asarray(kin.F))
    return float(np.sum(asm.volumes * model.element_moduli(theta, None) * w))


def test_the_reaction_is_the_derivative_of_the_strain_energy(box):
    """dW/ds = R . d along the tool's path s d (at equilibrium, f_int = 0 elsewhere)."""
    theta = np.array([5000.0])
    s, h = 1.0, 1e-3
    w = [
        _energy(m, theta, _path(m, theta))
        for m in (_model(box, load_scale=s + h), _model(box, load_scale=s - h))
    ]
    m = _model(box, load_scale=s)
    u = _path(m, theta)
    dw = (w[0] - w[1]) / (2 * h)
    power = float(m.reaction(theta, m.n_steps, u) @ np.asarray(D))
    assert power > 0
    assert dw == pytest.approx(power, rel=1e-5)


def test_the_reaction_scales_with_E_and_the_displacements_do_not(box):
    model = _model(box)
    a = _path(model, np.array([5000.0]))
    b = _path(model, np.array([10000.0]))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(a).max())
    ra = model.reaction(np.array([5000.0]), 4, a)
    rb = model.reaction(np.array([10000.0]), 4, b)
    np.testing.assert_allclose(rb, 2.0 * ra, rtol=1e-6)
    # the force-controlled grasp's reaction is (minus) its load: no E in it
    push = _model(box, "push-end")
    for E in (5000.0, 10000.0):
        r = push.reaction(np.array([E]), 4, _path(push, np.array([E])))
        np.testing.assert_allclose(r, [0.0, 0.0, 0.01], atol=1e-8)


def test_batched_steps_and_path_reuse_meet_the_tolerance(box):
    model = _model(box, steps=4)
    thetas = np.array([[4000.0], [5000.0], [6500.0]])
    states = np.zeros((3, model.n_state))
    for k in range(1, 5):
        states = model.step_many(thetas, k, states)
        for i, theta in enumerate(thetas):
            assert np.linalg.norm(model.residual(theta, k, states[i])) <= model.atol
        np.testing.assert_array_equal(  # the tool's dofs hold step k's values
            model.displacement_field(states[0])[model.driven_nodes],
            model.prescribed_displacement(k),
        )
    # the path's predictor is used (fewer factorizations than plain Newton)
    reuse, plain = _model(box, steps=8), _model(box, steps=8, path_reuse=False)
    ua, ub = _path(reuse, thetas[1]), _path(plain, thetas[1])
    np.testing.assert_allclose(ua, ub, rtol=0, atol=1e-8 * np.abs(ua).max())
    assert reuse.factorizations < plain.factorizations


def test_a_helper_process_sets_the_step_prescribed_displacement(box):
    """helper_solve (what a helper of option processes runs) on a fresh model."""
    from idbench_fem.fem.pairs import PendingPairs, helper_solve

    thetas = np.array([[3000.0], [8000.0]])
    here = _model(box)
    states = np.zeros((2, here.n_state))
    for k in (1, 2):
        states = here.step_many(thetas, k, states)
    helper = _model(box)  # as built in a helper: nothing prescribed yet
    x = states[:, helper._asm.unknown]
    got, _ = helper_solve(helper, 3, PendingPairs(thetas, x, x))
    want = here.step_many(thetas, 3, states)
    for i, theta in enumerate(thetas):
        full = helper._asm.embed(got[i])
        assert np.linalg.norm(here.residual(theta, 3, full)) <= here.atol
        scale = np.abs(want).max()
        np.testing.assert_allclose(full, want[i], rtol=0, atol=1e-6 * scale)


def test_sensitivity_of_the_markers_is_zero_with_one_E(box):
    model = _model(box)
    theta = np.array([5000.0])
    u = _path(model, theta)
    S = model.sensitivity(theta, model.n_steps, u)
    assert S.shape == (9, 1)
    assert np.abs(S).max() < 1e-6 * np.abs(model.observe(u)).max() / theta[0]


def test_a_grasp_with_force_and_displacement_or_kind_displacement_is_refused(box):
    raw = tomllib.loads(box.read_text())
    raw["manipulation"][0]["force"] = [0.0, 0.0, 1.0]
    with pytest.raises(ValueError, match="force and displacement"):
        parse_body(raw, "b.toml")
    raw["manipulation"][0].pop("force")
    raw["manipulation"][0]["kind"] = "displacement"
    with pytest.raises(ValueError) as exc:
        parse_body(raw, "b.toml")
    assert "grasp with displacement" in str(exc.value)
    assert "\n" not in str(exc.value)


def _config(body, observe, **kw):
    kw = {"steps": 4, "seeds": 1, "estimators": ("ro-ukf",), "noise": (1e-4,),
          "obs_points": (3,), "scenarios": ("pull-end",), **kw}  # fmt: skip
    return CompareConfig(model="solid", observe=observe,
                         model_settings={"solid": {"body": str(body)}},
                         **kw)  # fmt: skip


def test_markers_alone_are_refused_in_one_line(box):
    with pytest.raises(ConfigError) as exc:
        runs_of(_config(box, ("markers",)))
    text = str(exc.value)
    assert "'pull-end'" in text and "--observe force or markers+force" in text
    assert "\n" not in text
    assert runs_of(_config(box, ("markers+force",)))  # allowed with the force
    # a force-controlled grasp needs no force observed
    assert runs_of(_config(box, ("markers",), scenarios=("push-end",)))


def test_markers_only_is_one_line_on_the_command_line(box, tmp_path, capsys):
    argv = ["compare", "--model", "solid", "--model-option", f"body={box}",
            "--scenarios", "pull-end", "--steps", "3", "--seeds", "1",
            "--estimators", "rls", "--out", str(tmp_path / "o"), "-q"]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "pull-end" in err and "markers+force" in err and "\n" not in err


def test_ro_ukf_identifies_E_from_the_tool_force(box, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["compare", "--model", "solid", "--model-option", f"body={box}",
            "--scenarios", "pull-end", "--steps", "6", "--seeds", "1",
            "--estimators", "ro-ukf", "--observe", "markers+force",
            "--observe-option", "force.noise=2e-4", "--obs-every", "1",
            "--prior", "3000,2000", "--noise", "1e-4",
            "--out", str(out), "--format", "json", "-q"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    rows = json.loads(capsys.readouterr().out)
    assert [r["status"] for r in rows] == ["ok"]
    assert rows[0]["E_final"] == pytest.approx(5000.0, rel=0.03)


EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.parametrize("organ", ["liver", "kidney"])
def test_the_organ_grasp_examples_run_with_cloud_force_and_targets(
    organ, tmp_path, capsys
):
    """examples/ORGAN/grasp.toml shrunk: 200-node meshes, 4 steps."""
    pytest.importorskip("gmsh")  # the organs' meshes are generated on first use
    import pandas as pd

    out = tmp_path / organ
    argv = ["compare", "--config", str(EXAMPLES / organ / "grasp.toml"),
            "--meshes", "200", "--truth-mesh", "200", "--model-option",
            "reference=200", "--steps", "4", "--obs-every", "1",
            "--observe", "markers+force,cloud+force",
            "--observe-option", "cloud.points=200", "--out", str(out),
            "-q"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    runs = pd.read_parquet(out / "runs.parquet")
    assert sorted(runs["observe"]) == ["cloud+force", "markers+force"]
    assert set(runs["status"]) == {"ok"}, runs[["status", "error"]]
    assert runs["tre_final_mm"].notna().all() and (runs["tre_final_mm"] >= 0).all()
    traces = pd.read_parquet(out / "traces.parquet")
    assert traces["tre_mm"].notna().any()
    # the same example with markers alone is refused, naming its scenario
    argv = [*argv[:argv.index("--observe")], "--observe", "markers",
            "--out", str(tmp_path / "refused"), "-q"]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    scenario = tomllib.loads((EXAMPLES / organ / "grasp.toml").read_text())
    assert repr(scenario["compare"]["scenarios"][0]) in err


def test_a_driven_patch_on_the_fixed_region_is_refused_in_one_line(box):
    from idbench_fem.bodies import resolve

    raw = tomllib.loads(box.read_text())
    raw["manipulation"][0]["point"] = [0.0, 0.01, 0.01]  # on the clamped face
    body = parse_body(raw, str(box), box.parent)
    mesh = read_mesh(box.parent / "box.vtu")
    for check in (lambda: resolve.check(body, [mesh]),
                  lambda: SolidModel(body, mesh, "pull-end", mesh, 4, 3)):  # fmt: skip
        with pytest.raises(ValueError) as exc:
            check()
        text = str(exc.value)
        assert "'pull-end'" in text and "[fixed]" in text and "\n" not in text
