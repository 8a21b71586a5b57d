"""A modulus field on a solid: cells, truths, adjoints and linearizations.

Checked against what does not share their code: cell volumes against the
mesh's, the truth at its true cell values against the element moduli the
body gives, every derivative against central finite differences of the
model's own solves (equilibrium products, reaction, cloud distances).
"""

from __future__ import annotations

import numpy as np
import pytest
from support.bodies import write_beam_body, write_pulled_box

from idbench.core.observation_model import Frame
from idbench.observe.cloud import Cloud
from idbench_fem.bodies.description import load_body, parse_body
from idbench_fem.bodies.mesh import read_mesh
from idbench_fem.bodies.partition import assign, cell_geometry, tet_volumes
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid_settings import SolidSettings

K = 3
INCLUSION = """
[field]
cells = {cells}
length = 0.05
[[field.inclusion]]
region = {{ sphere = {{ centre = [0.1, 0.015, 0.015], radius = 0.03 }} }}
contrast = 3.0
"""


@pytest.fixture(scope="module")
def beam(tmp_path_factory):
    """The 12x3x3 cantilever body with an inclusion field (8 cells), its mesh."""
    tmp = tmp_path_factory.mktemp("beam")
    path, _ = write_beam_body(tmp, spec="12x3x3", markers=[
        [0.2, 0.0, 0.03], [0.2, 0.03, 0.03], [0.1, 0.0, 0.03], [0.05, 0.03, 0.03]])
    path.write_text(path.read_text() + INCLUSION.format(cells=8))
    body = load_body(path)
    return body, read_mesh(body.mesh.truth)


def solve(model, theta, k=K):
    u = model.reset()
    for j in range(1, k + 1):
        u = model.step(theta, j, u)
    return u


def test_cells_partition_the_body_and_touch_where_they_share_faces(beam):
    body, mesh = beam
    model = SolidModel(body, mesh, "end", mesh, K, 4)
    field = model.parameter_field
    assert model.parameters.names == tuple(f"E_cell{i:03d}" for i in range(8))
    vol = tet_volumes(mesh.points, mesh.tets)
    assert field.volumes.sum() == pytest.approx(vol.sum(), rel=1e-12)
    assert (field.areas > 0).all() and len(field.edges) >= 7  # connected body
    # a neighbour pair shares the area of the faces between them
    a, b = field.edges[0]
    c = model.element_regions
    assert {a, b} <= set(c.tolist())


def test_the_truth_at_its_true_cells_is_the_body_field_and_models_know_cells_only(
    beam,
):
    body, mesh = beam
    truth = SolidModel(body, mesh, "end", mesh, K, 4)  # the reference mesh
    true = np.array(truth.parameters.default)
    moduli = truth.element_moduli(true, None)
    inside = np.linalg.norm(
        mesh.points[mesh.tets].mean(1) - [0.1, 0.015, 0.015], axis=1) <= 0.03
    assert np.allclose(moduli[inside], 15000.0) and np.allclose(moduli[~inside], 5e3)
    # a cell's true value is the geometric mean of its elements' moduli
    vol = tet_volumes(mesh.points, mesh.tets)
    c = truth.element_regions
    gm = np.exp(np.bincount(c, vol * np.log(moduli)) / np.bincount(c, vol))
    assert np.allclose(true, gm)
    f = truth.parameter_field
    assert f.truth_inside is not None and f.truth_inside.max() > 0.5
    assert np.linalg.norm(f.truth_centre - [0.1, 0.015, 0.015]) < 0.005
    coarse = read_mesh(mesh.path)  # another object of the same file: the truth
    same = SolidModel(body, coarse, "end", mesh, K, 4)
    assert np.allclose(same.element_moduli(true, None), moduli)


def test_a_model_mesh_has_factors_one(beam, tmp_path):
    body, mesh = beam
    path, _ = write_beam_body(tmp_path, spec="6x2x2")
    other = read_mesh(path.with_name("beam-6x2x2.vtu"))
    model = SolidModel(body, other, "end", mesh, K, 4)
    assert model.parameters.default == SolidModel(
        body, mesh, "end", mesh, K, 4).parameters.default
    theta = np.arange(1.0, 9.0) * 1000
    assert np.allclose(model.element_moduli(theta, None),
                       theta[assign(other, _centres(model, mesh))])  # fmt: skip


def _centres(model, mesh):
    from idbench_fem.bodies.partition import kmeans_centres

    return kmeans_centres(mesh, 8, 0)


def test_known_region_gives_background_and_inclusion(beam):
    body, mesh = beam
    known = SolidSettings(field_cells="known")
    model = SolidModel(body, mesh, "end", mesh, K, 4, known)
    assert model.parameters.names == ("E_background", "E_inclusion")
    assert model.parameters.default == pytest.approx((5000.0, 15000.0))


def test_equilibrium_products_equal_finite_differences_and_each_other(beam):
    body, mesh = beam
    model = SolidModel(body, mesh, "end", mesh, K, 4)
    p = model.parameters.p
    rng = np.random.default_rng(0)
    theta = 5000 * np.exp(0.3 * rng.standard_normal(p))
    u = solve(model, theta)
    v = theta * rng.standard_normal(p)
    du = model.equilibrium_jvp(theta, K, u, v)
    h = 1e-4
    fd = (model.step(theta + h * v, K, u) - model.step(theta - h * v, K, u)) / (2 * h)
    assert np.linalg.norm(du - fd) <= 1e-6 * np.linalg.norm(fd)
    w = rng.standard_normal(model.n_state)
    J = model.equilibrium_jvp(theta, K, u, np.eye(p))
    assert np.allclose(model.equilibrium_vjp(theta, K, u, w), J.T @ w, rtol=1e-9)
    assert np.allclose(model.sensitivity(theta, K, u), model._obs @ J, rtol=1e-9)
    hu, ht = model.observation_jacobian(theta, K, u)
    assert np.allclose(hu @ u, model.observe(u)) and not ht.any()
    assert model.observation_points(K).shape == (12, 3)


def test_cloud_distances_linearize_to_their_finite_differences(beam):
    body, mesh = beam
    model = SolidModel(body, mesh, "end", mesh, K, 4)
    theta = np.full(model.parameters.p, 5000.0)
    u = solve(model, theta)
    vertices, triangles = model.surface(u)
    rng = np.random.default_rng(1)
    on = vertices[np.unique(triangles)]
    points = on[rng.choice(len(on), 40)] + 5e-4 * rng.standard_normal((40, 3))
    frame = Frame(K, {"points": points, "sigma": np.array(1e-3)})
    cloud = Cloud(gate=50.0)
    hu, ht = cloud.linearize(model, frame, theta, K, u)
    du = 1e-3 * rng.standard_normal(model.n_state)
    eps = 1e-3
    plus = cloud.predict(model, frame, theta, K, u + eps * du)
    minus = cloud.predict(model, frame, theta, K, u - eps * du)
    fd = (plus - minus) / (2 * eps)
    assert np.linalg.norm(hu @ du - fd) <= 1e-5 * np.linalg.norm(fd)
    assert not ht.any()


def test_grasp_force_linearizes_to_its_finite_differences(tmp_path):
    path = write_pulled_box(tmp_path, f"""
[[manipulation]]
name = "push"
kind = "grasp"
point = [0.1, 0.01, 0.01]
radius = 0.015
force = [0.0, 0.0, -0.05]
{INCLUSION.format(cells=4).replace("0.1, 0.015, 0.015", "0.05, 0.01, 0.01")}
""")
    text = path.read_text()
    body = parse_body(__import__("tomllib").loads(text), str(tmp_path / "box.toml"),
                      tmp_path)  # fmt: skip
    mesh = read_mesh(tmp_path / "box.vtu")
    for scenario in ("pull", "push"):
        model = SolidModel(body, mesh, scenario, mesh, K, 1)
        p = model.parameters.p
        theta = 5000 * np.exp(0.2 * np.random.default_rng(2).standard_normal(p))
        u = solve(model, theta)
        hu, ht = model.reaction_jacobian(theta, K, u)
        r = model.reaction
        for j in range(p):
            e = np.eye(p)[j] * 1e-3 * theta[j]
            fd = (r(theta + e, K, u) - r(theta - e, K, u)) / 2e-3 / theta[j]
            assert np.allclose(ht[:, j], fd, rtol=1e-6, atol=1e-12)
        du = 1e-6 * np.random.default_rng(3).standard_normal(model.n_state)
        fd = (r(theta, K, u + du) - r(theta, K, u - du)) / 2
        assert np.allclose(hu @ du, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
        # the total derivative of the tool's force: through u and directly
        v = theta * np.random.default_rng(4).standard_normal(p)
        total = hu @ model.equilibrium_jvp(theta, K, u, v) + ht @ v
        h = 1e-4
        fd = (r(theta + h * v, K, model.step(theta + h * v, K, u))
              - r(theta - h * v, K, model.step(theta - h * v, K, u))) / (2 * h)
        # (a force-controlled grasp's reaction is its load: no E, both ~0)
        scale = np.abs(r(theta, K, u)).max()
        assert np.allclose(total, fd, rtol=1e-5, atol=1e-6 * scale)


def test_field_tables_are_checked_in_one_line(tmp_path):
    path, _ = write_beam_body(tmp_path)
    base = path.read_text()
    for extra, match in (
        ("[field]\ncells = 0\n", "cells = 0"),
        ("[field]\ncells = 'known'\n", "needs a \\[\\[field.inclusion\\]\\]"),
        ("[field]\nlength = -1.0\n", "length"),
        ("[field]\nsmooth = 1\n", "unknown key 'smooth'"),
        ("[field]\n[[field.inclusion]]\nregion = 'x'\n", "needs region and contrast"),
    ):
        path.write_text(base + extra)
        with pytest.raises(ValueError, match=match):
            load_body(path)
    with pytest.raises(ValueError, match="field_cells"):
        SolidSettings(field_cells=0)
    with pytest.raises(ValueError, match="field_length"):
        SolidSettings(field_length=0.0)


def test_cell_geometry_refuses_an_empty_cell(beam):
    _, mesh = beam
    cells = np.zeros(len(mesh.tets), dtype=np.int64)
    with pytest.raises(ValueError, match="cell 1 holds no tetrahedron"):
        cell_geometry(mesh, cells, 2)
