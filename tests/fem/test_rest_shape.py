"""The stress-free shape of a body imaged under gravity, re-loaded, is the image."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import idbench
from idbench_fem.bodies.catalog import get_body, mesh_file
from idbench_fem.bodies.description import load_body
from idbench_fem.models.rest_shape import stress_free
from idbench_fem.models.solid import SolidModel, make_model
from idbench_fem.models.solid_settings import SolidSettings

BODY = """
[mesh]
truth = "{mesh}"
[material]
law = "neo-hookean"
E = 16000.0
nu = 0.45
density = 1060.0
[fixed]
name = "ligament"
[[manipulation]]
name = "sag"
kind = "gravity"
acceleration = [0.0, 0.0, -9.81]
[[manipulation]]
name = "lift"
kind = "grasp"
point = [0.037, 0.032, -0.030]
radius = 0.01
force = [0.0, 0.0, 0.2]
[markers]
points = [[0.0761, 0.0229, 0.0118], [0.0584, 0.0402, 0.0118]]
[shape_error]
grid = [4, 3, 3]
{reference}
"""


@pytest.fixture(scope="module")
def liver200(tmp_path_factory):
    """A small liver (about 200 nodes) hanging from its ligament, imaged sagged.

    Stiffer than the shipped liver (16 kPa): hanging from its ligament alone,
    a 4 kPa lobe sags 5 cm, which no organ does (others hold it).
    """
    mesh = mesh_file(get_body("liver"), "200")
    folder = tmp_path_factory.mktemp("rest")
    plain = folder / "plain.toml"
    plain.write_text(BODY.format(mesh=mesh, reference=""))
    imaged = folder / "imaged.toml"
    imaged.write_text(
        BODY.format(mesh=mesh, reference='[reference]\nimaged_under = "sag"')
    )
    return plain, imaged


def model(body, manipulation="sag", steps=8):
    sc = idbench.Scenario(
        manipulation, {"body": str(body), "manipulation": manipulation}
    )
    return make_model(idbench.ModelSpec("truth", sc, steps, 2, {"body": str(body)}))


def loaded_shape(m):
    theta = np.asarray(m.parameters.default, dtype=float)
    u = m.reset()
    for k in range(1, m.n_steps + 1):
        u = m.step(theta, k, u)
    return m.mesh()[0] + m.displacement_field(u)


def test_the_rest_shape_reloaded_is_the_imaged_shape(liver200):
    plain, imaged = liver200
    image = model(plain).mesh()[0]  # the mesh as imaged
    sagged = model(plain)
    sag = np.linalg.norm(loaded_shape(sagged) - image, axis=1).max()
    assert sag > 1e-3  # gravity moves it by millimetres: a real correction
    rest = model(imaged)  # built on the stress-free shape
    X = rest.mesh()[0]
    assert np.linalg.norm(X - image, axis=1).max() > 0.5 * sag
    back = loaded_shape(rest)  # re-loaded along its own ramp
    assert np.linalg.norm(back - image, axis=1).max() < 1e-4  # 0.1 mm
    # other manipulations start from the stress-free shape too
    assert np.allclose(model(imaged, "lift").mesh()[0], X)


def test_an_unknown_imaging_load_gets_one_line(liver200, tmp_path):
    _, imaged = liver200
    bad = tmp_path / "bad.toml"
    bad.write_text(
        imaged.read_text().replace('imaged_under = "sag"', 'imaged_under = "x"')
    )
    with pytest.raises(ValueError, match="imaged_under = 'x'") as err:
        load_body(bad)
    assert "\n" not in str(err.value)


def test_the_true_rest_shape_is_recovered_from_its_loaded_image(liver200):
    plain, _ = liver200
    m = model(plain)
    body, mesh = m.body, m.mesh_data
    rest = mesh.points
    image = loaded_shape(m)  # the truth: this rest shape, sagged

    def build(points):
        moved = dataclasses.replace(mesh, points=points)
        settings = SolidSettings(path_reuse=False)
        return SolidModel(body, moved, "sag", moved, 8, 1, settings)

    found = stress_free(build, image, tolerance=1e-7)
    assert np.linalg.norm(found.points - rest, axis=1).max() < 1e-4  # 0.1 mm
    assert found.mismatch[0] > 1e-3 and found.mismatch[-1] <= 1e-7
