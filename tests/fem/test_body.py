"""Body descriptions: parsing, selectors, loads (totals, scikit-fem), bad input."""

from __future__ import annotations

import copy
import textwrap

import meshio
import numpy as np
import pytest

from idbench import closest_on_triangles
from idbench_fem.bodies import description as bodies
from idbench_fem.bodies import resolve
from idbench_fem.bodies.loads import (
    gravity_forces,
    nodal_forces,
    patch_forces,
    pressure_forces,
    traction_forces,
)
from idbench_fem.bodies.mesh import from_arrays, read_mesh
from idbench_fem.bodies.regions import Region
from idbench_fem.bodies.surface import inside

L, W, H = 0.2, 0.03, 0.04


@pytest.fixture(scope="module")
def beam():
    from skfem import MeshTet

    m = MeshTet.init_tensor(
        np.linspace(0, L, 9), np.linspace(0, W, 3), np.linspace(0, H, 4)
    )
    p, t = m.p.T, m.t.T
    centroids = p[t].mean(axis=1)
    return from_arrays(
        p,
        t,
        "beam",
        cell_sets={
            "left": np.flatnonzero(centroids[:, 0] < L / 2),
            "right": np.flatnonzero(centroids[:, 0] >= L / 2),
        },
        point_sets={"clamp": np.flatnonzero(np.isclose(p[:, 0], 0))},
    )


def _raw(**over):
    raw = {
        "mesh": {"truth": "beam.msh"},
        "material": {"law": "svk", "E": 3000.0, "nu": 0.45, "density": 1060.0},
        "fixed": {"name": "clamp"},
        "manipulation": [
            {"name": "push", "kind": "traction", "region": {"box": {
                "lower": [L - 1e-9, -1, -1], "upper": [1, 1, 1]}},
             "traction": [0.0, -10.0, 0.0]},
            {"name": "squeeze", "kind": "pressure", "region": {"box": {
                "lower": [L / 2 - 1e-9, -1, -1], "upper": [1, 1, 1]}},
             "pressure": 50.0},
            {"name": "sag", "kind": "gravity", "acceleration": [0, 0, -9.81]},
            {"name": "lift", "kind": "grasp", "point": [L - 0.03, W / 2, H + 0.001],
             "radius": 0.012, "force": [0.0, 0.1, 0.3]},
        ],
        "markers": {"points": [[L, 0, H], [L, W, H + 0.001]]},
        "shape_error": {"grid": [8, 2, 2], "margin": 0.002},
    }  # fmt: skip
    raw = copy.deepcopy(raw)
    for key, value in over.items():
        if value is None:
            raw.pop(key)
        else:
            raw[key] = value
    return raw


def _body(**over):
    return bodies.parse_body(_raw(**over), "body.toml")


def test_parse_and_resolve(beam):
    b = _body()
    assert b.material == bodies.Material("svk", 3000.0, 0.45, 1060.0)
    assert [m.kind for m in b.manipulations] == ["traction", "pressure", "gravity",
                                                 "grasp"]  # fmt: skip
    assert b.manipulation("lift").region == Region(
        patch=((L - 0.03, W / 2, H + 0.001), 0.012)
    )
    assert b.parameter_names == ("E",)
    resolve.check(b, [beam])
    fixed = resolve.fixed_nodes(b, beam)
    np.testing.assert_array_equal(fixed, np.flatnonzero(beam.points[:, 0] == 0))
    markers = resolve.marker_points(b, beam)
    np.testing.assert_allclose(markers, [[L, 0, H], [L, W, H]], atol=1e-15)
    grid = resolve.shape_error_points(b, beam)
    assert len(grid) == 8 * 2 * 2  # all cell centres are >= 2 mm inside
    b2 = _body(parameters={"regions": ["left", "right"]})
    assert b2.parameter_names == ("E_left", "E_right")
    regions = resolve.element_regions(b2, beam)
    np.testing.assert_array_equal(
        regions, beam.points[beam.tets].mean(1)[:, 0] >= L / 2
    )
    assert b2.material.make().name == "svk"


def test_boundary_is_outward_and_closed(beam):
    n2a = beam.facet_normals()
    np.testing.assert_allclose(n2a.sum(axis=0), 0, atol=1e-15)
    # divergence theorem: V = 1/3 sum x_f . n_f A_f
    x = beam.points[beam.facets].mean(axis=1)
    assert np.einsum("fi,fi->", x, n2a) / 6 == pytest.approx(L * W * H, rel=1e-12)
    assert beam.volumes.sum() == pytest.approx(L * W * H, rel=1e-12)


def test_totals_equal_the_requested_loads(beam):
    b = _body()
    rho = b.material.density
    f = nodal_forces(b.manipulation("push"), beam, rho, t=0.5)
    np.testing.assert_allclose(f.sum(0), 0.5 * np.array([0, -10.0, 0]) * W * H)
    assert np.all(f[beam.points[:, 0] < L - 1e-9] == 0)
    f = nodal_forces(b.manipulation("sag"), beam, rho)
    np.testing.assert_allclose(f.sum(0), [0, 0, -9.81 * rho * L * W * H], rtol=1e-12)
    f = nodal_forces(b.manipulation("lift"), beam, rho, t=0.25)
    np.testing.assert_allclose(f.sum(0), [0, 0.025, 0.075], rtol=1e-12)
    loaded = np.flatnonzero(np.abs(f).sum(1))
    assert np.all(beam.points[loaded, 2] == H)  # on the top face, near the point
    near = np.linalg.norm(beam.points[loaded] - [L - 0.03, W / 2, H], axis=1)
    assert np.all(near < 0.04)
    # pressure on the right half's boundary: -p sum(n A); on the end face alone -p A x
    f = nodal_forces(b.manipulation("squeeze"), beam, rho)
    end = beam.facet_sets["right"][
        np.all(np.isclose(beam.points[beam.facets[beam.facet_sets["right"]], 0], L), 1)
    ]
    np.testing.assert_allclose(
        pressure_forces(beam, end, 50.0).sum(0), [-50.0 * W * H, 0, 0], atol=1e-15
    )
    # the open right half: sum n A = the missing cut face x = L/2, normal -x
    np.testing.assert_allclose(f.sum(0), [-50.0 * W * H, 0, 0], atol=1e-12)


def test_loads_match_scikit_fem_forms(beam):
    from skfem import (
        Basis,
        ElementTetP1,
        ElementVector,
        FacetBasis,
        LinearForm,
        MeshTet,
        asm,
    )
    from skfem.helpers import dot

    m = MeshTet(beam.points.T.copy(), beam.tets.T.copy())
    e = ElementVector(ElementTetP1())
    g = np.array([0.0, -9.81, 1.0])
    t = np.array([1.0, -2.0, 3.0])

    @LinearForm
    def body_force(v, w):
        return 1060.0 * dot(g, v)

    @LinearForm
    def surface(v, w):
        return dot(t, v)

    @LinearForm
    def press(v, w):
        return -50.0 * dot(w.n, v)

    def nodal(vec, basis):
        return vec[basis.nodal_dofs.T.ravel()].reshape(-1, 3)

    basis = Basis(m, e)
    ref = nodal(asm(body_force, basis), basis)
    np.testing.assert_allclose(gravity_forces(beam, 1060.0, g), ref, atol=1e-14)
    end = m.facets_satisfying(lambda x: np.isclose(x[0], L))
    fb = FacetBasis(m, e, facets=end)
    mine = np.flatnonzero(np.all(np.isclose(beam.points[beam.facets, 0], L), 1))
    np.testing.assert_allclose(
        traction_forces(beam, mine, t), nodal(asm(surface, fb), basis), atol=1e-15
    )
    np.testing.assert_allclose(
        pressure_forces(beam, mine, 50.0), nodal(asm(press, fb), basis), atol=1e-15
    )
    allb = FacetBasis(m, e)
    np.testing.assert_allclose(
        pressure_forces(beam, np.arange(len(beam.facets)), 50.0),
        nodal(asm(press, allb), basis),
        atol=1e-15,
    )
    f = patch_forces(beam, mine, t)
    np.testing.assert_allclose(f, traction_forces(beam, mine, t / (W * H)), atol=1e-15)


def test_closest_point_on_triangle_against_brute_force():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(5, 3, 3))
    pts = rng.normal(size=(40, 3)) * 2
    rep = np.repeat(pts, len(tri), axis=0)
    q, bary = closest_on_triangles(rep, *(np.tile(tri[:, i], (len(pts), 1))
                                          for i in range(3)))  # fmt: skip
    np.testing.assert_allclose(q, np.einsum("mk,mki->mi", bary, np.tile(
        tri, (len(pts), 1, 1))), atol=1e-12)  # fmt: skip
    q, bary = q.reshape(len(pts), len(tri), 3), bary.reshape(len(pts), len(tri), 3)
    assert np.all(bary >= -1e-12)
    np.testing.assert_allclose(bary.sum(-1), 1)
    s = np.linspace(0, 1, 201)
    a, b = np.meshgrid(s, s)
    keep = a + b <= 1
    w = np.stack([1 - a[keep] - b[keep], a[keep], b[keep]], 1)  # (S, 3)
    samples = np.einsum("sk,fki->fsi", w, tri)
    for f in range(len(tri)):
        d_brute = np.linalg.norm(pts[:, None] - samples[f][None], axis=2).min(1)
        d = np.linalg.norm(q[:, f] - pts, axis=1)
        assert np.all(d <= d_brute + 1e-12)
        assert np.all(d >= d_brute - 0.01)  # the sampling's resolution


def _one_line(exc_info, *words):
    text = str(exc_info.value)
    assert "\n" not in text
    for w in words:
        assert w in text, text


@pytest.mark.parametrize(
    ("over", "words"),
    [
        ({"fixed": None}, ["no [fixed] region", "rigidly"]),
        ({"material": {"density": -1060.0}}, ["density = -1060", ">= 0"]),
        ({"material": {"law": "mooney"}}, ["law = 'mooney'", "svk, neo-hookean"]),
        ({"material": {"nu": 0.5}}, ["nu = 0.5", "(-1, 0.5)"]),
        ({"material": {"E": 0}}, ["E = 0", "> 0"]),
        ({"manipulation": [{"name": "pull", "kind": "displacement"}]},
         ["'pull'", "displacement", "cannot be identified", "force"]),
        ({"manipulation": [{"name": "x", "kind": "spin"}]}, ["kind = 'spin'", "grasp"]),
        ({"manipulation": [{"name": "g", "kind": "grasp", "point": [0, 0, 0],
                            "radius": 0.01}]}, ["'g'", "needs force"]),
        ({"fixed": {"box": {"lower": [0, 0, 0], "upper": [0, 1, 1]}}},
         ["[fixed]", "lower < upper"]),
        ({"fixed": {"cube": 1}}, ["[fixed]", "exactly one of name, box"]),
        ({"markers": {}}, ["[markers]", "exactly one of points"]),
        ({"parameters": {"regions": ["left"]}}, ["regions = ['left']", "two or more"]),
        ({"shape_error": {"grid": [4, 0, 2]}}, ["grid = [4, 0, 2]", ">= 1"]),
        ({"mesh": {}}, ["[mesh]", "truth = None"]),
    ],
)  # fmt: skip
def test_bad_descriptions_give_one_line(over, words):
    raw = _raw()
    for key, value in over.items():
        if value is None:
            raw.pop(key)
        elif key == "material":
            raw[key] = raw[key] | value
        else:
            raw[key] = value
    with pytest.raises(ValueError) as exc:
        bodies.parse_body(raw, "body.toml")
    _one_line(exc, "body.toml", *words)


@pytest.mark.parametrize(
    ("over", "call", "words"),
    [
        ({"fixed": {"name": "ligament"}}, "fixed",
         ["region 'ligament' is not in mesh 'beam'", "clamp, left, right"]),
        ({"fixed": {"sphere": {"centre": [1, 1, 1], "radius": 0.01}}}, "fixed",
         ["[fixed] region sphere", "contains no node"]),
        ({"fixed": {"box": {"lower": [-1, -1, -1], "upper": [1e-9, 1e-9, 1]}}},
         "fixed", ["on one line", "rotate"]),
        ({"manipulation": [{"name": "lift", "kind": "grasp", "point": [L / 2, W / 2,
                            H + 0.05], "radius": 0.01, "force": [0, 0, 1]}]},
         "loads", ["manipulation 'lift'", "from the surface", "radius 0.01"]),
        ({"manipulation": [{"name": "p", "kind": "pressure", "region": {"half_space":
                            {"point": [1, 0, 0], "normal": [1, 0, 0]}},
                            "pressure": 1.0}]},
         "loads", ["manipulation 'p'", "half_space", "no boundary facet"]),
        ({"markers": {"points": [[L / 2, W / 2, H + 0.02]]}}, "markers",
         ["[markers] point 1", "outside the body of mesh 'beam' (",
          "snap_distance = 0.005 m (the default)"]),
        ({"markers": {"points": [[L / 2, W / 2, H / 2]], "snap_distance": 0.001}},
         "markers", ["[markers] point 1", "inside the body of mesh 'beam' ("]),
        ({"parameters": {"regions": ["left", {"box": {"lower": [0, 0, 0],
                                                       "upper": [L, W, H]}}]}},
         "regions", ["tetrahedron", "more than one region", "partition"]),
        ({"parameters": {"regions": ["left", "clamp"]}}, "regions",
         ["'clamp' is not a volume region", "left, right"]),
        ({"shape_error": {"margin": 0.5}}, "grid", ["[shape_error]", "0.5 m inside"]),
        ({"material": {"E": 3e3, "E_regions": {"tumour": 2e4}}}, "moduli",
         ["[material] E_regions 'tumour' is not in mesh", "clamp, left, right"]),
    ],
)  # fmt: skip
def test_bad_regions_give_one_line(beam, over, call, words):
    b = _body(**over)
    fn = {
        "fixed": lambda: resolve.fixed_nodes(b, beam),
        "loads": lambda: [nodal_forces(m, beam, 1000.0) for m in b.manipulations],
        "markers": lambda: resolve.marker_points(b, beam),
        "regions": lambda: resolve.element_regions(b, beam),
        "grid": lambda: resolve.shape_error_points(b, beam),
        "moduli": lambda: resolve.element_moduli(b, beam),
    }[call]
    with pytest.raises(ValueError) as exc:
        fn()
    _one_line(exc, *words)


def test_mesh_files_without_tets_or_inverted(tmp_path):
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
    path = tmp_path / "surface.vtu"
    meshio.write(path, meshio.Mesh(p, [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(ValueError) as exc:
        read_mesh(path)
    _one_line(exc, "surface.vtu", "no 'tetra' cells", "triangle")
    folded = np.array([[0, 1, 2, 3], [1, 2, 3, 0]])  # the same tet twice
    with pytest.raises(ValueError) as exc:
        from_arrays(p, folded, "folded")
    _one_line(exc, "folded", "inverted")
    with pytest.raises(ValueError) as exc:
        read_mesh(tmp_path / "nope.msh")
    _one_line(exc, "nope.msh", "does not exist")


def test_body_file_with_a_gmsh_liver(tmp_path):
    pytest.importorskip("gmsh")
    text = textwrap.dedent(
        """
        [mesh]
        truth = "m/liver-n250.msh"
        models = ["m/liver-n120.msh"]
        generate = { geometry = "liver", sizes = [120, 250] }

        [material]
        law = "neo-hookean"
        E = 4000.0
        nu = 0.47
        density = 1060.0

        [fixed]
        name = "ligament"

        [[manipulation]]
        name = "grasp-lift"
        kind = "grasp"
        point = [0.04, 0.045, -0.03]
        radius = 0.012
        force = [0.0, 0.0, 0.5]

        [[manipulation]]
        name = "sag-90"
        kind = "gravity"
        acceleration = [0.0, -9.81, 0.0]

        [markers]
        region = "anterior"

        [shape_error]
        grid = [8, 5, 4]
        margin = 0.004
        """
    )
    (tmp_path / "body.toml").write_text(text)
    b = bodies.load_body(tmp_path / "body.toml")
    paths = resolve.mesh_paths(b)  # generates the two meshes
    assert [p.name for p in paths] == ["liver-n120.msh", "liver-n250.msh"]
    meshes = [read_mesh(p) for p in paths]
    resolve.check(b, meshes)
    coarse, truth = meshes
    # the same fixed patch on both: its area is resolution-independent up to facets
    areas = [m.facet_areas(m.facet_sets["ligament"]).sum() for m in meshes]
    assert areas[0] == pytest.approx(areas[1], rel=0.1)
    markers = resolve.marker_points(b, truth)
    assert np.all(markers[:, 1] >= -1e-9)  # anterior: y >= 0
    grid = resolve.shape_error_points(b, truth)
    assert len(grid) > 10
    assert inside(coarse, grid).all()  # the margin keeps them locatable
    f = nodal_forces(b.manipulation("sag-90"), coarse, 1060.0)
    assert f.sum(0)[1] == pytest.approx(-9.81 * 1060.0 * coarse.volumes.sum())
    assert b.material.make(E=1.0).linear_in_modulus


EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.parametrize(("geometry", "size"), [("liver", 150), ("kidney", 250)])
def test_example_bodies_resolve_on_small_meshes(tmp_path, geometry, size):
    pytest.importorskip("gmsh")
    from idbench_fem.bodies.geometry import make_meshes

    b = bodies.load_body(EXAMPLES / geometry / "body.toml")
    assert b.material.law == "neo-hookean"
    assert 0.45 <= b.material.nu <= 0.49
    assert 1000 <= b.material.density <= 1100
    assert 1000 <= b.material.E <= 10000
    assert b.mesh.truth.name == f"{geometry}-n16000.msh"
    assert b.mesh.truth.parent == EXAMPLES / geometry / "meshes"
    (path,) = make_meshes(geometry, [size], tmp_path)
    mesh = read_mesh(path)
    resolve.check(b, [mesh])  # every name and selector resolves
    for m in b.manipulations:
        total = nodal_forces(m, mesh, b.material.density).sum(0)
        if m.driven:  # no load: the patch's nodes move, none of them fixed
            np.testing.assert_array_equal(total, 0.0)
            nodes = resolve.driven_nodes(b, m.name, mesh)
            assert len(nodes) >= 3
            assert not np.intersect1d(nodes, resolve.fixed_nodes(b, mesh)).size
        elif m.kind == "grasp":
            np.testing.assert_allclose(total, m.vector, rtol=1e-12)
        if m.kind == "gravity":
            expect = b.material.density * mesh.volumes.sum() * np.array(m.vector)
            np.testing.assert_allclose(total, expect, rtol=1e-12)
    E = resolve.element_moduli(b, mesh)
    if geometry == "kidney":
        inc = mesh.cell_sets["inclusion"]
        assert b.parameter_names == ("E_parenchyma", "E_inclusion")
        np.testing.assert_array_equal(resolve.element_regions(b, mesh)[inc], 1)
        assert np.all(E[inc] == 24000.0)
        assert np.sum(E == 6000.0) == len(mesh.tets) - len(inc)
    else:
        assert b.parameter_names == ("E",)
        assert np.all(E == 4000.0)
        assert len(resolve.marker_points(b, mesh)) == 8
