"""Accelerated chords accept a Newton step that raises |r| (as _modified_newton)."""

from __future__ import annotations

import tomllib

import numpy as np
from support.helpers import write_box_mesh

from idbench_fem.bodies.description import parse_body
from idbench_fem.bodies.mesh import read_mesh
from idbench_fem.fem import batched
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid_settings import SolidSettings

BODY = """
[mesh]
truth = "box.vtu"
models = ["box.vtu"]
[material]
law = "neo-hookean"
E = 5000.0
nu = 0.4
density = 1000.0
[fixed]
box = { lower = [-0.001, -1.0, -1.0], upper = [0.001, 1.0, 1.0] }
[[manipulation]]
name = "push"
kind = "grasp"
point = [0.1, 0.01, 0.01]
radius = 0.015
force = [0.0, 0.0, -0.01]
[markers]
points = [[0.05, 0.0, 0.02]]
snap_distance = 0.002
[shape_error]
grid = [6, 2, 2]
[parameters]
regions = [{ slab = { index = 0, count = 2 } }, { slab = { index = 1, count = 2 } }]
"""


def test_sigma_points_converge_where_the_first_newton_step_raises_r(
    tmp_path, monkeypatch
):
    write_box_mesh(tmp_path / "box.vtu", 7, 0.1, 0.02)
    body = parse_body(tomllib.loads(BODY), str(tmp_path / "b.toml"), tmp_path)
    mesh = read_mesh(tmp_path / "box.vtu")
    thetas = 5000.0 * np.array([[1.0, 1.0], [1.0, 1.0], [1 / 1.5, 1.5], [1.5, 1 / 1.5]])
    out = {}
    for accelerate in (False, True):
        monkeypatch.setattr(batched, "ACCELERATE_FROM_DOFS", 0 if accelerate else 10**9)
        model = SolidModel(body, mesh, "push", mesh, 1, 1, SolidSettings())
        assert batched.accelerates(model, 2) is accelerate
        out[accelerate] = model.step_many(thetas, 1, np.zeros((4, model.n_state)))
        for theta, u in zip(thetas, out[accelerate], strict=True):
            assert np.linalg.norm(model.residual(theta, 1, u)) <= max(
                model.rtol * np.linalg.norm(model.external_force(1)), model.atol
            )
    scale = np.abs(out[False]).max()
    np.testing.assert_allclose(out[True], out[False], rtol=0, atol=1e-6 * scale)
