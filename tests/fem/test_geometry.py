"""gmsh organ-like meshes: files, groups, refinement, orientation, volume."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("gmsh")
meshio = pytest.importorskip("meshio")

from idbench_fem.bodies import geometry  # noqa: E402


@pytest.fixture(scope="module")
def liver(tmp_path_factory):
    out = tmp_path_factory.mktemp("liver")
    return geometry.mesh_series("liver", [400, 150], out)


@pytest.fixture(scope="module")
def kidney(tmp_path_factory):
    out = tmp_path_factory.mktemp("kidney")
    return geometry.mesh_series("kidney", [0.012, 0.007], out)


def _tets(m):
    return np.concatenate([c.data for c in m.cells if c.type == "tetra"])


def _signed_volumes(points, tets):
    x = points[tets]
    return (
        np.einsum(
            "ti,ti->t",
            x[:, 1] - x[:, 0],
            np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]),
        )
        / 6.0
    )


def _set_cells(m, name, kind):
    """Cells of type ``kind`` in the meshio cell set ``name``."""
    blocks = [
        c.data[idx]
        for c, idx in zip(m.cells, m.cell_sets[name], strict=True)
        if c.type == kind and len(idx)
    ]
    return np.concatenate(blocks) if blocks else np.empty((0, 4), dtype=int)


def _monte_carlo(inside, lo, hi, n=1_000_000, seed=0):
    x = np.random.default_rng(seed).uniform(lo, hi, size=(n, 3))
    return inside(x).mean() * np.prod(np.subtract(hi, lo))


def _in_ellipsoid(x, centre, axes):
    return (((x - np.asarray(centre)) / np.asarray(axes)) ** 2).sum(axis=1) <= 1.0


def test_files_sorted_coarse_to_fine_and_near_target(liver):
    assert [i.path.name for i in liver] == ["liver-n150.msh", "liver-n400.msh"]
    assert all(i.path.is_file() for i in liver)
    assert liver[0].nodes < liver[1].nodes
    for info, target in zip(liver, (150, 400), strict=True):
        assert abs(info.nodes / target - 1) <= 0.05
    assert liver[0].h > liver[1].h


def test_meshio_reads_groups_and_counts(liver, kidney):
    for info in liver:
        m = meshio.read(info.path)
        assert {"ligament", "anterior", "inferior_edge", "posterior", "liver"} <= set(
            m.cell_sets
        )
        tets = _tets(m)
        assert len(np.unique(tets)) == info.nodes == len(m.points)
        assert len(tets) == info.tets
        assert len(_set_cells(m, "liver", "tetra")) == len(tets)
        for name in ("ligament", "anterior", "inferior_edge", "posterior"):
            assert len(_set_cells(m, name, "triangle")) > 0, name
    m = meshio.read(kidney[0].path)
    assert {"hilum", "anterior", "posterior", "parenchyma", "inclusion"} <= set(
        m.cell_sets
    )


def test_surface_groups_cover_the_boundary_once(liver):
    m = meshio.read(liver[1].path)
    tets = _tets(m)
    faces = np.sort(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]], axis=2)
    faces = faces.reshape(-1, 3)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    boundary = {tuple(f) for f in uniq[counts == 1]}
    grouped = [
        tuple(f)
        for name in ("ligament", "anterior", "inferior_edge", "posterior")
        for f in np.sort(_set_cells(m, name, "triangle"), axis=1)
    ]
    assert len(grouped) == len(set(grouped)) == len(boundary)
    assert set(grouped) == boundary


def test_tets_positively_oriented(liver, kidney):
    for info in (*liver, *kidney):
        m = meshio.read(info.path)
        v = _signed_volumes(m.points, _tets(m))
        assert v.min() > 0, info.path.name


def test_liver_volume_near_ellipsoid_union_and_converges(liver):
    lo, hi = (-0.08, -0.05, -0.04), (0.09, 0.05, 0.04)
    exact = _monte_carlo(
        lambda x: np.logical_or.reduce(
            [_in_ellipsoid(x, c, a) for c, a in geometry.LIVER_ELLIPSOIDS]
        ),
        lo,
        hi,
    )  # MC standard error ~0.1%
    errors = []
    for info in liver:
        m = meshio.read(info.path)
        errors.append(_signed_volumes(m.points, _tets(m)).sum() / exact - 1)
    assert all(-0.12 < e < 0.01 for e in errors), errors  # inscribed: smaller
    assert abs(errors[1]) < abs(errors[0])
    # size: about 15 x 10 x 8 cm
    m = meshio.read(liver[1].path)
    extent = np.ptp(m.points, axis=0)
    np.testing.assert_allclose(extent, (0.16, 0.10, 0.08), rtol=0.1)


def test_kidney_inclusion_and_hilum(kidney):
    centre, radius = geometry.KIDNEY_INCLUSION
    notch = geometry.KIDNEY_NOTCH
    exact = _monte_carlo(
        lambda x: (
            _in_ellipsoid(x, *geometry.KIDNEY_ELLIPSOID) & ~_in_ellipsoid(x, *notch)
        ),
        (-0.055, -0.03, -0.02),
        (0.055, 0.03, 0.02),
    )
    sphere = 4 / 3 * math.pi * radius**3
    errors = []
    for info in kidney:
        m = meshio.read(info.path)
        inc = _set_cells(m, "inclusion", "tetra")
        par = _set_cells(m, "parenchyma", "tetra")
        assert len(inc) + len(par) == len(_tets(m))
        errors.append(_signed_volumes(m.points, inc).sum() / sphere - 1)
    assert -0.3 < errors[0] < errors[1] < 0  # inscribed, converging
    v_all = _signed_volumes(m.points, _tets(m)).sum()
    assert v_all == pytest.approx(exact, rel=0.05)
    # inclusion cells lie in the sphere; hilum triangles on the notch ellipsoid
    assert np.all(np.linalg.norm(m.points[inc] - centre, axis=2) <= radius * 1.001)
    hilum = m.points[_set_cells(m, "hilum", "triangle")].reshape(-1, 3)
    level = (((hilum - notch[0]) / notch[1]) ** 2).sum(axis=1)
    np.testing.assert_allclose(level, 1.0, atol=1e-4)  # OCC surface tolerance


def test_deterministic(tmp_path, liver):
    a = geometry.make_meshes("kidney", [0.015], tmp_path / "a")
    b = geometry.make_meshes("kidney", [0.015], tmp_path / "b")
    assert a[0].read_bytes() == b[0].read_bytes()
    # a node-count target gives the same mesh whatever else is in the list
    (c,) = geometry.make_meshes("liver", [150], tmp_path / "c")
    assert c.read_bytes() == liver[0].path.read_bytes()


@pytest.mark.parametrize(
    ("name", "sizes", "match"),
    [
        ("spleen", [200], "geometry 'spleen': allowed are liver, kidney"),
        ("liver", [], "sizes: give at least one"),
        ("liver", [-0.01], "size -0.01: give a node count"),
        ("liver", [10], "size 10: give a node count"),
    ],
)
def test_bad_input(tmp_path, name, sizes, match):
    with pytest.raises(ValueError, match=match):
        geometry.make_meshes(name, sizes, tmp_path)
