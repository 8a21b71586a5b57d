"""The beam preset (a body of the solid model) against independent references.

Each step's displacement field within 1e-10 (relative to the largest
displacement) of Newton on scikit-fem's SVK forms (tests/support/oracles), on
6x2x2 and 9x2x2 meshes, for each beam scenario (the preset was checked equal to the
``SvkBeam`` class it replaced, to 1e-15, before that class was deleted).
"""

from __future__ import annotations

import numpy as np
import pytest

from idbench import ModelSpec
from idbench_fem.bodies import box
from idbench_fem.models.beam import make_model
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_fem.models.beam_settings import BeamSettings


def _oracle_solution(points, tets, fixed, traction, n_steps, E, nu):
    """Displacements (N, 3) after each step by Newton on the scikit-fem forms."""
    from support.oracles import svk_forms

    free = np.setdiff1d(np.arange(len(points)), fixed)
    f = svk_forms.end_traction(points, tets, traction)[free].ravel()
    u = np.zeros((len(points), 3))
    fields = []
    for k in range(1, n_steps + 1):
        fk = (k / n_steps) * f
        for _ in range(12):  # to round-off: quadratic convergence, ~5 iterations
            r, K = svk_forms.residual_and_tangent(
                points, tets, free, u, np.full(len(tets), E), nu
            )
            du = np.linalg.solve(K.toarray(), fk - r)
            u[free] += du.reshape(-1, 3)
            if np.abs(du).max() <= 1e-14 * np.abs(u).max():
                break
        fields.append(u.copy())
    return fields


@pytest.mark.parametrize("mesh", ["6x2x2", "9x2x2"])
@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.name)
def test_preset_equals_the_oracle(mesh, scenario):
    """Each step's displacement field equals Newton on scikit-fem's SVK forms."""
    spec = ModelSpec(mesh, scenario, 2, 2, BeamSettings(nu=0.4, rtol=1e-13))
    model = make_model(spec)
    E = 6000.0
    points, tets = model.mesh()
    load = scenario.load
    traction = load["magnitude"] * np.asarray(load["direction"])
    expected = _oracle_solution(points, tets, model.fixed_nodes, traction, 2, E, 0.4)
    assert len(model.fixed_nodes) == 9  # the nodes at x = 0
    assert np.all(points[model.fixed_nodes, 0] == 0.0)
    u = model.reset()
    for k in range(1, 3):
        u = model.step(np.array([E]), k, u)
        ref = expected[k - 1]
        np.testing.assert_allclose(
            model.displacement_field(u), ref, rtol=0, atol=1e-10 * np.abs(ref).max()
        )
    tip = model.probe("tip", u)
    centre = np.flatnonzero(np.all(np.isclose(points, [0.2, 0.015, 0.015]), axis=1))
    np.testing.assert_allclose(tip, expected[-1][centre[0]], atol=1e-12)


def test_registered_beam_is_the_solid_model_built_by_build():
    import idbench
    from idbench_fem.models.beam import build
    from idbench_fem.models.solid import SolidModel

    registry = idbench.build_registry()
    spec = ModelSpec("6x2x2", registry.scenario("bend-y"), 2)
    model = registry.model("svk-beam")(spec)
    assert type(model) is SolidModel
    assert model.describe()["body"] == "svk-beam"
    built = build(box.parse("6x2x2"), SCENARIOS[0], n_steps=2)
    assert type(built) is SolidModel and built.describe() == model.describe()


def test_beam_body_options_in_a_toml_body(tmp_path):
    """What the beam needs is a body option any TOML body can use."""
    from idbench_fem.bodies.description import parse_body
    from idbench_fem.bodies.regions import region_cells

    raw = {
        "mesh": {"truth": "x.vtu"},
        "fixed": {"half_space": {"point": [0, 0, 0], "normal": [-1, 0, 0]}},
        "manipulation": [{"name": "pull", "kind": "gravity",
                          "acceleration": [0, -9.81, 0]}],
        "markers": {"points": [[0.2, 0.0, 0.03]], "placement": "volume"},
        "shape_error": {"grid": [4, 2, 2], "locate": "contained"},
        "parameters": {"regions": [{"slab": {"index": 0, "count": 2}},
                                   {"slab": {"index": 1, "count": 2}}],
                       "bounds": [1.0, 1e8]},
        "probe": [{"name": "tip", "point": [0.2, 0.015, 0.015]}],
    }  # fmt: skip
    body = parse_body(raw, "b.toml", tmp_path)
    assert body.markers.placement == "volume"
    assert body.shape_error.locate == "contained"
    assert body.parameter_bounds == (1.0, 1e8)
    assert body.probes == (("tip", (0.2, 0.015, 0.015)),)
    mesh = box.parse("9x2x2")
    first, second = (region_cells(mesh, r) for r in body.parameter_regions)
    assert len(first) + len(second) == len(mesh.tets)
    assert len(np.intersect1d(first, second)) == 0
    for bad, match in (
        ({"markers": {"points": [[0, 0, 0]], "placement": "inside"}}, "placement"),
        ({"parameters": {"regions": [{"slab": {"index": 2, "count": 2}}, "a"]}},
         "index and count"),
        ({"parameters": {"bounds": [5.0, 1.0]}}, "lower < upper"),
        ({"probe": [{"name": "tip"}]}, "point"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            parse_body({**raw, **bad}, "b.toml", tmp_path)


def test_one_truth_serves_every_marker_count_and_grid():
    """The truth's cache key leaves out markers and grid (they do not change states)."""
    from idbench.truth.simulate import truth_key

    keys = set()
    for markers, grid in ((2, (20, 4, 4)), (6, (20, 4, 4)), (2, (10, 2, 2))):
        settings = BeamSettings(grid=grid)
        model = make_model(ModelSpec("6x2x2", SCENARIOS[0], 2, markers, settings))
        keys.add(truth_key(model, np.array([5000.0])))
    assert len(keys) == 1
    other = make_model(ModelSpec("6x2x2", SCENARIOS[1], 2, 2))  # another load
    assert truth_key(other, np.array([5000.0])) not in keys
