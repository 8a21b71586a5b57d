"""Mesh specs, boundary detection, marker/grid placement and P1 probes."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from idbench_fem.bodies import box
from idbench_fem.bodies.regions import region_facets, region_nodes
from idbench_fem.fem.interpolation import (
    grid_points,
    interpolation_matrix,
    marker_points,
)


def _clamped(m):
    return region_nodes(m, box.clamped_face(m))


def _loaded(m):
    return region_facets(m, box.loaded_face(m))


def test_divisions_spec():
    m = box.parse("14x3x3")
    assert m.points.shape == (15 * 4 * 4, 3)
    assert m.tets.shape == (14 * 9 * 6, 4)
    np.testing.assert_allclose(m.upper - m.lower, [box.LENGTH, box.WIDTH, box.HEIGHT])
    assert len(_clamped(m)) == 16
    assert np.all(m.points[_clamped(m), 0] == 0.0)
    assert len(_loaded(m)) == 2 * 9
    np.testing.assert_allclose(m.facet_areas(_loaded(m)).sum(), box.WIDTH * box.HEIGHT)
    x = m.points[m.tets]
    vol = np.einsum(
        "ti,ti->t", x[:, 1] - x[:, 0], np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])
    )
    assert np.all(vol > 0)
    np.testing.assert_allclose(vol.sum() / 6, 0.2 * 0.03 * 0.03)


@pytest.mark.parametrize(
    ("target", "expected"), [("240", (14, 3, 3)), ("239", (14, 3, 3))]
)
def test_node_count_spec(target, expected):
    assert box.divisions_for_nodes(int(target)) == expected
    assert len(box.parse(target).points) == 240


@pytest.mark.parametrize("target", [500, 1000, 4000, 11000])
def test_node_count_is_about_right_and_near_cubic(target):
    nx, ny, nz = box.divisions_for_nodes(target)
    assert ny == nz
    assert abs((nx + 1) * (ny + 1) ** 2 / target - 1) < 0.1
    assert 0.5 < (0.2 / nx) / (0.03 / ny) < 2


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("0x3x3", "0x3x3"),
        ("3x3", "'3x3'.*NXxNYxNZ"),
        ("abc", "'abc'.*node count"),
        ("", "NXxNYxNZ"),
        ("5", "'5'.*between 8"),
        ("no/such/file.vtu", "no/such/file.vtu"),
    ],
)
def test_bad_specs_are_named(spec, match):
    with pytest.raises(ValueError, match=match):
        box.parse(spec)


@pytest.mark.parametrize("suffix", [".vtu", ".msh"])
def test_meshio_round_trip(tmp_path, suffix):
    m = box.parse("6x2x2")
    path = tmp_path / f"beam{suffix}"
    kwargs = {"file_format": "gmsh22", "binary": False} if suffix == ".msh" else {}
    meshio.write(path, meshio.Mesh(m.points, [("tetra", m.tets)]), **kwargs)
    back = box.parse(str(path))
    np.testing.assert_allclose(back.points, m.points)
    np.testing.assert_array_equal(back.tets, m.tets)
    np.testing.assert_array_equal(_clamped(back), _clamped(m))
    np.testing.assert_allclose(
        back.facet_areas(_loaded(back)), m.facet_areas(_loaded(m))
    )


def test_file_without_tets(tmp_path):
    path = tmp_path / "tri.vtu"
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    meshio.write(path, meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(ValueError, match="no 'tetra' cells"):
        box.parse(str(path))


def test_markers_order():
    lo, hi = np.zeros(3), np.array([0.2, 0.03, 0.03])
    p = marker_points(8, lo, hi)
    np.testing.assert_allclose(
        p[:4], [[0.2, 0, 0.03], [0.2, 0.03, 0.03], [0.2, 0, 0], [0.2, 0.03, 0]]
    )
    assert np.all(p[4:, 2] == 0.03) and np.all(p[4:, 0] < 0.2)
    assert set(p[4:, 1]) == {0.0, 0.03}
    with pytest.raises(ValueError):
        marker_points(0, lo, hi)


def test_grid_strictly_inside():
    lo, hi = np.zeros(3), np.array([0.2, 0.03, 0.03])
    g = grid_points((4, 4, 20), lo, hi)
    assert g.shape == (320, 3)
    assert np.all(g > lo) and np.all(g < hi)


def test_probe_interpolates_linear_fields_exactly():
    m = box.parse("5x2x2")
    free = np.ones(len(m.points), bool)
    free[_clamped(m)] = False
    f2f = np.full(3 * len(m.points), -1)
    f2f[np.repeat(free, 3)] = np.arange(3 * free.sum())
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0, 0], [0.2, 0.03, 0.03], size=(50, 3))
    pts = np.vstack([pts, marker_points(6, m.lower, m.upper)])
    c = rng.normal(size=3)
    field = m.points[:, :1] * c  # linear in x, zero on the clamped face
    P = interpolation_matrix(pts, m.points, m.tets, f2f)
    got = (P @ field[free].ravel()).reshape(-1, 3)
    np.testing.assert_allclose(got, pts[:, :1] * c, atol=1e-14)
    with pytest.raises(ValueError, match="outside"):
        interpolation_matrix(np.array([[0.3, 0.01, 0.01]]), m.points, m.tets, f2f)


def test_a_legacy_gmsh_mesh_gets_its_conversion_command(tmp_path):
    from idbench_fem.bodies.mesh import read_mesh

    legacy = tmp_path / "old.msh"
    legacy.write_text("$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n"
                      "$ELM\n1\n1 4 1 1 4 1 2 3 4\n$ENDELM\n")  # fmt: skip
    with pytest.raises(ValueError) as exc:
        read_mesh(legacy)
    text = str(exc.value)
    assert "meshio cannot read it" in text and "legacy gmsh v1 mesh" in text
    assert f"gmsh {legacy} -save -format msh22 -o {tmp_path / 'old-v22.msh'}" in text


def test_a_point_outside_a_model_mesh_is_named_as_the_toml_counts(tmp_path):
    from support.helpers import write_box_mesh

    from idbench_fem.bodies.catalog import get_mesh
    from idbench_fem.bodies.description import parse_body
    from idbench_fem.models.points import place_points

    write_box_mesh(tmp_path / "box.vtu", 4, 0.1, 0.02)
    body = parse_body({
        "mesh": {"truth": "box.vtu"}, "fixed": {"box": {"lower": [-1, -1, -1],
                                                        "upper": [0.001, 1, 1]}},
        "manipulation": [{"name": "g", "kind": "gravity",
                          "acceleration": [0, 0, -9.81]}],
        "markers": {"points": [[0.05, 0.01, 0.01], [0.2, 0.01, 0.01]],
                    "placement": "volume"},
    }, "box.toml", tmp_path)  # fmt: skip
    mesh = get_mesh(tmp_path / "box.vtu")
    f2f = np.arange(3 * len(mesh.points))
    with pytest.raises(ValueError) as exc:
        place_points(body, mesh, mesh, 2, f2f)
    assert "box.toml: [markers] point 2 at [0.2, 0.01, 0.01] lies outside" in str(
        exc.value
    )
    assert "(36 nodes)" in str(exc.value)
