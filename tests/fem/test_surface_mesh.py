"""``idbench mesh``: a surface file to tetrahedral meshes, or one line saying where.

The synthetic organ is an ellipsoid of 320 triangles (60 x 40 x 30 mm
semi-axes) written as STL and OBJ; copies with a fold, a hole and a
non-manifold edge are refused before gmsh, naming the file and a place.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.helpers import ellipsoid_surface, folded, write_surface

from idbench.cli.commands import main
from idbench_fem.bodies.mesh import read_mesh
from idbench_fem.bodies.surface_file import crossings, merged, read_surface


@pytest.fixture(scope="module")
def surfaces(tmp_path_factory):
    folder = tmp_path_factory.mktemp("surfaces")
    v, f = ellipsoid_surface(2)
    write_surface(folder / "organ.stl", v, f)
    write_surface(folder / "organ.obj", v, f)
    write_surface(folder / "fold.stl", folded(v), f)
    write_surface(folder / "open.obj", v, f[:-2])
    return folder


def one_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("idbench: error: "), err
    return err[0]


@pytest.mark.parametrize("name", ["organ.stl", "organ.obj"])
def test_mesh_meets_each_node_count_without_inverted_tets(surfaces, tmp_path,
                                                          capsys, name):  # fmt: skip
    out = tmp_path / "meshes"
    argv = ["mesh", str(surfaces / name), "--sizes", "150,400", "--scale", "0.001",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    shown = capsys.readouterr()
    for n in (150, 400):
        mesh = read_mesh(out / f"organ-n{n}.msh")
        assert abs(len(mesh.points) / n - 1) <= 0.10
        x = mesh.points[mesh.tets]
        assert np.all(np.einsum("ti,ti->t", x[:, 1] - x[:, 0],
                                np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])) > 0)
        assert {"surface", "volume"} <= set(mesh.names)
        # metres: the ellipsoid's 60 mm semi-axis
        assert 0.05 < mesh.points[:, 0].max() <= 0.0601
    table = shown.out.splitlines()
    assert table[0].split()[:5] == ["mesh", "asked", "nodes", "tets", "inverted"]
    rows = [line.split() for line in table[2:4]]
    assert [r[4] for r in rows] == ["0", "0"]  # inverted
    assert all(0.9 < float(r[-1]) < 1.0 for r in rows)  # volume / surface's
    assert f'truth = "{(out / "organ-n400.msh").as_posix()}"' in shown.out
    assert f'models = ["{(out / "organ-n150.msh").as_posix()}"]' in shown.out
    progress = [line for line in shown.err.splitlines() if "nodes (asked" in line]
    assert len(progress) == 2  # a line per size


def test_a_fold_is_refused_in_one_line_saying_where(surfaces, tmp_path, capsys):
    argv = ["mesh", str(surfaces / "fold.stl"), "--sizes", "150", "--scale",
            "0.001", "--out", str(tmp_path)]  # fmt: skip
    assert main(argv) == 2
    err = one_error(capsys)
    assert "fold.stl" in err and "crosses itself" in err
    near = err[err.index("near (") + 6 : err.index(") m")]
    x = np.array([float(v) for v in near.split(",")])
    assert abs(x[0] + 0.06) < 0.005  # where the tip went through: x = -60 mm
    assert not list(tmp_path.glob("*.msh"))


def test_an_open_surface_is_refused_naming_an_edge(surfaces, tmp_path, capsys):
    argv = ["mesh", str(surfaces / "open.obj"), "--sizes", "150", "--out",
            str(tmp_path)]  # fmt: skip
    assert main(argv) == 2
    err = one_error(capsys)
    assert "open.obj" in err and "is open" in err and "edge(s)" in err
    assert err.count(") m") == 2  # from (x, y, z) m to (x, y, z) m


def test_a_non_manifold_surface_is_refused(tmp_path, capsys):
    # two closed tetrahedra sharing an edge: four triangles on that edge
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0],
                  [0, 0, -1]], dtype=float)  # fmt: skip
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3],
                  [0, 1, 4], [0, 5, 1], [0, 4, 5], [1, 5, 4]])  # fmt: skip
    write_surface(tmp_path / "pair.ply", v, f)
    assert main(["mesh", str(tmp_path / "pair.ply"), "--sizes", "50"]) == 2
    err = one_error(capsys)
    assert "is not manifold" in err and "from (0, 0, 0) m to (1, 0, 0) m" in err


def test_other_files_and_scales_get_one_line(tmp_path, capsys):
    (tmp_path / "organ.txt").write_text("nothing")
    assert main(["mesh", str(tmp_path / "organ.txt"), "--sizes", "100"]) == 2
    assert "give an STL, OBJ or PLY surface" in one_error(capsys)
    assert main(["mesh", str(tmp_path / "none.stl"), "--sizes", "100"]) == 2
    assert "does not exist" in one_error(capsys)


def test_crossings_of_a_clean_surface_and_of_a_fold():
    v, f = ellipsoid_surface(3)
    assert len(crossings(v, f)[0]) == 0
    bad = folded(v)
    pairs, where = crossings(bad, f)
    tip = int(v[:, 0].argmax())
    assert len(pairs) and np.all((f[pairs[:, 0]] == tip).any(axis=1)
                                 | (f[pairs[:, 1]] == tip).any(axis=1))  # fmt: skip
    assert np.all(where[:, 0] < -50.0)


def test_a_surface_is_read_merged_and_oriented(tmp_path):
    v, f = ellipsoid_surface(2)
    flipped = f.copy()
    flipped[::3] = flipped[::3, ::-1]  # a third of the triangles the wrong way
    write_surface(tmp_path / "o.obj", v, flipped)
    s = read_surface(tmp_path / "o.obj", 0.001)
    exact = 4 / 3 * np.pi * 0.06 * 0.04 * 0.03
    assert len(s.points) == 162 and 0.95 < s.volume / exact < 1.0
    # an STL repeats each vertex per triangle; merged back
    soup = merged("soup", v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3))
    assert len(soup.points) == 162 and len(soup.triangles) == 320
