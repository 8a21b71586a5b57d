"""Body descriptions written for the tests: the cantilever beam as a body."""

from __future__ import annotations

import meshio

from idbench_fem.bodies.box import parse as beam_mesh


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
