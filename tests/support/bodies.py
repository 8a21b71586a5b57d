"""Body descriptions written for the tests: the cantilever beam as a body, a
pulled box."""

from __future__ import annotations

import meshio

from idbench_fem.bodies.box import parse as beam_mesh
from support.helpers import write_box_mesh


def write_beam_body(tmp_path, spec="8x2x2", law="svk", nu=0.45, E=5000.0,
                    traction=(0.0, -8.9, 0.0), markers=None):  # fmt: skip
    """The cantilever as a body: a .vtu mesh, x = 0 fixed, traction on x = L."""
    beam = beam_mesh(spec)
    path = tmp_path / f"beam-{spec}.vtu"
    meshio.write(path, meshio.Mesh(beam.points, [("tetra", beam.tets)]))
    (x0, y0, z0), (x1, y1, z1) = beam.lower.tolist(), beam.upper.tolist()
    eps = 1e-9
    markers = markers or [[x1, y0, z1], [x1, y1, z1]]
    text = f"""
[mesh]
truth = "{path.name}"
[material]
law = "{law}"
E = {E}
nu = {nu}
[fixed]
box = {{ lower = [{x0 - eps}, {y0 - 1}, {z0 - 1}], upper = [{x0 + eps}, {y1 + 1}, {z1 + 1}] }}
[[manipulation]]
name = "end"
kind = "traction"
region = {{ box = {{ lower = [{x1 - eps}, {y0 - 1}, {z0 - 1}], upper = [{x1 + eps}, {y1 + 1}, {z1 + 1}] }} }}
traction = {list(traction)}
[[manipulation]]
name = "pull"
kind = "traction"
region = {{ box = {{ lower = [{x1 - eps}, {y0 - 1}, {z0 - 1}], upper = [{x1 + eps}, {y1 + 1}, {z1 + 1}] }} }}
traction = [250.0, 0.0, 0.0]
[markers]
points = {markers}
[shape_error]
grid = [6, 3, 3]
"""  # noqa: E501
    body = tmp_path / f"beam-{spec}-{law}.toml"
    body.write_text(text)
    return body, beam


FIELD_MARKERS = [[0.2, 0.0, 0.03], [0.2, 0.03, 0.03], [0.1, 0.0, 0.03],
                 [0.1, 0.03, 0.03], [0.05, 0.0, 0.03], [0.15, 0.03, 0.03]]  # fmt: skip
"""Six markers on the top of the 12x3x3 beam, along it: a field's tests."""


PULLED_BOX = """
[mesh]
truth = "box.vtu"
[material]
law = "neo-hookean"
E = 5000.0
nu = 0.4
[fixed]
box = { lower = [-0.001, -1.0, -1.0], upper = [0.001, 1.0, 1.0] }
[[manipulation]]
name = "pull"
kind = "grasp"
point = [0.1, 0.01, 0.01]
radius = 0.015
displacement = [0.0, 0.0, -0.004]
[markers]
points = [[0.05, 0.0, 0.02]]
[shape_error]
grid = [6, 2, 2]
"""
"""A 0.1 x 0.02 x 0.02 box clamped at x = 0, its end pulled down by a grasp
(``pull``), one marker (:func:`write_pulled_box`)."""


def write_pulled_box(folder, extra=""):  # type: ignore[no-untyped-def]
    """``folder``/box.vtu (9 nodes along x) and box.toml, :data:`PULLED_BOX`
    followed by ``extra`` (more TOML); the body TOML's path."""
    write_box_mesh(folder / "box.vtu", 9, 0.1, 0.02)
    path = folder / "box.toml"
    path.write_text(PULLED_BOX + extra)
    return path
