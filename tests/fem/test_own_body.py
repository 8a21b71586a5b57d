"""A body of one's own, described from the README alone, given as ``body=FILE``.

The body is a small clamped box with three tiny meshes written by meshio
(their files are not named ``*-nN``), a dead pressure and a grasp; nothing is
listed in ``IDBENCH_BODIES``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.helpers import write_box_mesh

import idbench
from idbench.cli.commands import main
from idbench.plan.config import CompareConfig, ConfigError
from idbench.run.compare import compare, runs_of
from idbench.run.session import Session

L, W = 0.1, 0.02
SIZES = {"box-coarse": 4, "box-mid": 6, "box-fine": 10}
"""Mesh file stem -> nodes along x (3 x 3 across): 36, 54 and 90 nodes."""

BODY = """
[mesh]
truth = "box-fine.vtu"
models = ["box-coarse.vtu", "box-mid.vtu"]

[material]
law = "neo-hookean"
E = 5000.0
nu = 0.4
density = 1000.0

[fixed]
box = { lower = [-0.001, -1.0, -1.0], upper = [0.001, 1.0, 1.0] }

[[manipulation]]
name = "press-top"
kind = "pressure"
region = { box = { lower = [0.05, -1.0, 0.019], upper = [0.11, 1.0, 1.0] } }
pressure = 20.0

[[manipulation]]
name = "pull-end"
kind = "grasp"
point = [0.1, 0.01, 0.01]
radius = 0.015
force = [0.0, 0.0, -0.002]

[markers]
points = [[0.1, 0.0, 0.02], [0.1, 0.02, 0.02], [0.05, 0.01, 0.02]]
snap_distance = 0.002

[shape_error]
grid = [6, 2, 2]
"""


@pytest.fixture
def box(tmp_path, monkeypatch):
    """The body TOML path; no IDBENCH_BODIES."""
    monkeypatch.delenv("IDBENCH_BODIES", raising=False)
    for stem, n in SIZES.items():
        write_box_mesh(tmp_path / f"{stem}.vtu", n, L, W)
    path = tmp_path / "box.toml"
    path.write_text(BODY)
    return path


def config(body, **kw) -> CompareConfig:
    kw = {"steps": 3, "seeds": 1, "estimators": ("rls",), **kw}
    return CompareConfig(model="solid", model_settings={"solid": {"body": str(body)}},
                         **kw)  # fmt: skip


def test_body_proposes_its_meshes_scenario_and_prior(box):
    resolved = config(box).resolve(idbench.build_registry())
    assert resolved.scenarios == ("press-top",)
    assert resolved.meshes == ("box-coarse", "box-mid")
    assert resolved.truth_mesh == "box-fine"
    assert resolved.prior == (2500.0, 2500.0)  # E / 2, E / 2
    quick = CompareConfig(model="solid", quick=True,
                          model_settings={"solid": {"body": str(box)}})  # fmt: skip
    assert quick.resolve(idbench.build_registry()).meshes == ("box-coarse", "box-mid")
    given = config(box, meshes=("36",), scenarios=("pull-end",))
    resolved = given.resolve(idbench.build_registry())
    assert resolved.meshes == ("36",) and resolved.scenarios == ("pull-end",)


def test_default_body_keeps_the_registered_defaults():
    reg = idbench.build_registry()
    for settings in ({}, {"solid": {"body": "liver"}}):
        got = CompareConfig(model="solid", model_settings=settings).resolve(reg)
        want = reg.models["solid"].defaults
        assert (got.truth_mesh, got.meshes, got.scenarios, got.prior) == (
            want.truth_mesh, want.meshes, want.scenarios, want.prior,
        )  # fmt: skip


def test_compare_runs_the_body_by_default(box, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["compare", "--model", "solid", "--model-option", f"body={box}",
            "--steps", "3", "--seeds", "1", "--estimators", "rls", "--out",
            str(out), "--format", "json", "-q"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    rows = json.loads(capsys.readouterr().out)
    assert {r["scenario"] for r in rows} == {"press-top"}
    assert {r["mesh"] for r in rows} == {"box-coarse", "box-mid"}
    assert {r["status"] for r in rows} == {"ok"}


def test_a_fresh_worker_finds_the_body_scenarios(box):
    """A worker's session builds its registry from the plugins alone."""
    runs = runs_of(config(box, scenarios=("pull-end",)))
    fresh = Session(idbench.build_registry())
    assert "pull-end" not in fresh.registry.scenarios
    spec = runs[0]
    scenario = fresh.scenario(spec, "pull-end")
    assert scenario.load == {"body": str(box), "manipulation": "pull-end"}
    assert scenario.transfer == "press-top"
    assert fresh.model(spec, spec.mesh).n_nodes == 36


def test_spawned_workers_run_the_body(box, tmp_path, monkeypatch):
    monkeypatch.setenv("IDBENCH_START_METHOD", "spawn")
    runs, _ = compare(config(box, scenarios=("pull-end",)), tmp_path / "o", jobs=2)
    assert set(runs["status"]) == {"ok"}, runs[["status", "error"]]
    assert set(runs["scenario"]) == {"pull-end"}


def test_node_count_selects_a_mesh_whatever_its_name(box):
    from idbench_fem.bodies.catalog import get_body, mesh_file

    body = get_body(str(box))
    assert mesh_file(body, "36").name == "box-coarse.vtu"
    assert mesh_file(body, "90").name == "box-fine.vtu"
    with pytest.raises(ValueError) as exc:
        mesh_file(body, "37")
    text = str(exc.value)
    assert "37" in text and "box-coarse 36" in text and "box-mid 54" in text
    assert "\n" not in text


def test_a_scenario_of_another_body_is_refused(box):
    with pytest.raises(ConfigError) as exc:
        runs_of(config(box, scenarios=("grasp-lift",)))
    text = str(exc.value)
    assert "'grasp-lift' is a manipulation of body 'liver'" in text
    assert "press-top, pull-end" in text


def _slab(tmp_path):
    """A gmsh slab: volume group 'tissue', surface groups 'clamp' and 'end'."""
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        v = gmsh.model.occ.addBox(0, 0, 0, L, W, W)
        gmsh.model.occ.synchronize()
        faces = [s for _, s in gmsh.model.getBoundary([(3, v)], oriented=False)]
        x = {s: gmsh.model.occ.getCenterOfMass(2, s)[0] for s in faces}
        gmsh.model.addPhysicalGroup(3, [v], name="tissue")
        gmsh.model.addPhysicalGroup(2, [s for s in faces if x[s] < 1e-9], name="clamp")
        gmsh.model.addPhysicalGroup(2, [s for s in faces if x[s] > L - 1e-9],
                                    name="end")  # fmt: skip
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.012)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(tmp_path / "slab.msh"))
    finally:
        gmsh.finalize()
    text = BODY.replace('"box-fine.vtu"', '"slab.msh"').replace(
        '["box-coarse.vtu", "box-mid.vtu"]', '["slab.msh"]'
    )
    text = text.replace(
        "box = { lower = [-0.001, -1.0, -1.0], upper = [0.001, 1.0, 1.0] }",
        'name = "clamp"',
    )
    return text


@pytest.mark.parametrize("kind", ["traction", "pressure"])
def test_a_surface_load_on_a_volume_region_is_refused(tmp_path, kind):
    text = _slab(tmp_path)
    load = "traction = [0.0, 0.0, -5.0]" if kind == "traction" else "pressure = 5.0"
    text = text.replace(
        'name = "press-top"\nkind = "pressure"\n'
        "region = { box = { lower = [0.05, -1.0, 0.019], upper = [0.11, 1.0, 1.0] } }"
        "\npressure = 20.0",
        f'name = "press-top"\nkind = "{kind}"\nregion = "tissue"\n{load}',
    )
    assert 'region = "tissue"' in text
    path = tmp_path / "slab.toml"
    path.write_text(text)
    out = tmp_path / "out"
    # the volume load is the transfer target of pull-end: refused before any run
    for scenarios in (("press-top",), ("pull-end",)):
        with pytest.raises(ConfigError) as exc:
            compare(config(path, scenarios=scenarios), out)
        message = str(exc.value)
        assert "'tissue' is a volume region" in message, message
        assert kind in message and "\n" not in message
        assert not (out / "manifest.json").exists()
    surface = text.replace('region = "tissue"', 'region = "end"')
    path.write_text(surface)
    runs, _ = compare(config(path, scenarios=("press-top",)), out)
    assert set(runs["status"]) == {"ok"}, runs[["status", "error"]]


def test_info_solid_shows_whole_help_texts(capsys):
    assert main(["info", "solid"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "e.g. to keep SVK in the range it can follow)" in text
    assert "Not part of the run's identity." in text
    assert "Give the comparison's truth mesh when it is not the body's." in text


def test_nodal_forces_refuse_a_volume_name_but_not_a_surface_name():
    from skfem import MeshTet

    from idbench_fem.bodies.loads import nodal_forces
    from idbench_fem.bodies.manipulations import Manipulation
    from idbench_fem.bodies.mesh import from_arrays
    from idbench_fem.bodies.regions import Region

    m = MeshTet.init_tensor(np.linspace(0, L, 4), np.linspace(0, W, 2),
                            np.linspace(0, W, 2))  # fmt: skip
    p, t = m.p.T, m.t.T
    mesh = from_arrays(p, t, "slab", cell_sets={"tissue": np.arange(len(t))},
                       point_sets={"end": np.flatnonzero(np.isclose(p[:, 0], L))})
    for kind, extra in (("traction", {"vector": (0.0, 0.0, -5.0)}),
                        ("pressure", {"pressure": 5.0})):  # fmt: skip
        volume = Manipulation("m", kind, Region(name="tissue"), **extra)
        with pytest.raises(ValueError, match="'tissue' is a volume region"):
            nodal_forces(volume, mesh, 1000.0)
        surface = Manipulation("m", kind, Region(name="end"), **extra)
        f = nodal_forces(surface, mesh, 1000.0)
        assert np.all(f[~np.isclose(p[:, 0], L)] == 0)  # only the end face


def test_a_body_without_model_meshes_asks_for_them(box):
    text = box.read_text().replace(
        'models = ["box-coarse.vtu", "box-mid.vtu"]\n', ""
    )
    box.write_text(text)
    with pytest.raises(ConfigError, match="proposes no default for meshes"):
        runs_of(config(box))
    assert len(runs_of(config(box, meshes=(str(box.parent / "box-coarse.vtu"),)))) == 1
