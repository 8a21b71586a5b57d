"""The solid building blocks compose: body + loads + laws + a reference Newton."""

from __future__ import annotations

import numpy as np
import pytest
from support.oracles import general_law

from idbench_fem.bodies import description as bodies
from idbench_fem.bodies import resolve
from idbench_fem.bodies.loads import nodal_forces
from idbench_fem.bodies.mesh import read_mesh
from idbench_fem.fem.materials import NeoHookean, Svk

pytest.importorskip("gmsh")


@pytest.fixture(scope="module")
def liver(tmp_path_factory):
    from idbench_fem.bodies.geometry import make_meshes

    (path,) = make_meshes("liver", [150], tmp_path_factory.mktemp("m"))
    return read_mesh(path)


@pytest.fixture(scope="module")
def body():
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    return bodies.load_body(root / "examples" / "liver" / "body.toml")


@pytest.mark.parametrize("name", ["grasp-lift", "lateral-push", "sag-90"])
def test_equilibrium_and_convergence(liver, body, name):
    m = body.manipulation(name)
    fixed = resolve.fixed_nodes(body, liver)
    E = resolve.element_moduli(body, liver)
    rho = body.material.density
    sol = general_law.solve(
        body.material.make(), liver.points, liver.tets, E, fixed,
        lambda t: nodal_forces(m, liver, rho, t), steps=4,
    )  # fmt: skip
    assert max(sol.iterations) <= 6  # quadratic convergence
    f_ext = nodal_forces(m, liver, rho)
    applied = f_ext.sum(0)
    # global equilibrium: the support reaction balances the total load
    support = sol.internal[fixed] - f_ext[fixed]
    np.testing.assert_allclose(
        support.sum(0), -applied, atol=1e-8 * np.abs(applied).max()
    )
    # objectivity: internal forces exert no moment about the deformed positions
    x = liver.points + sol.u
    moment = np.cross(x, sol.internal).sum(0)
    lever = np.abs(x).max() * np.abs(sol.internal).max()
    np.testing.assert_allclose(moment, 0, atol=1e-10 * lever)
    assert np.all(sol.u[fixed] == 0)
    assert 1e-4 < np.abs(sol.u).max() < 0.05  # mm to cm, as documented


def test_neo_hookean_and_svk_agree_at_small_load(liver, body):
    m = body.manipulation("grasp-lift")
    fixed = resolve.fixed_nodes(body, liver)
    E = np.full(len(liver.tets), 4000.0)
    diffs = []
    for scale in (0.02, 0.01):
        u = [
            general_law.solve(
                law(nu=0.47), liver.points, liver.tets, E, fixed,
                lambda t, s=scale: s * nodal_forces(m, liver, 1060.0, t), steps=1,
            ).u
            for law in (Svk, NeoHookean)
        ]  # fmt: skip
        diffs.append(np.abs(u[0] - u[1]).max() / np.abs(u[0]).max())
    # relative difference O(strain): halves with the load
    assert diffs[0] / diffs[1] == pytest.approx(2, rel=0.15)
    assert diffs[1] < 0.01
