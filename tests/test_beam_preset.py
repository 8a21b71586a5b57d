"""The beam preset (a body of the solid model) against independent references.

Each step's displacement field within 1e-10 (relative to the largest
displacement) of Newton on scikit-fem's SVK forms (tests/oracles), on 6x2x2
and 9x2x2 meshes, for each beam scenario; and (while it exists) equal to the
SvkBeam class it replaces.
"""

from __future__ import annotations

import numpy as np
import pytest

from idbench import ModelSpec
from idbench_fem.models.beam import make_model, make_preset
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_fem.models.beam_settings import BeamSettings

SETTINGS = (
    BeamSettings(),
    BeamSettings(parameters="E_regions", inclusion=(0.05, 0.12, 0, 0.03, 0, 0.03),
                 grid=(6, 2, 2)),
)  # fmt: skip


@pytest.mark.parametrize("mesh", ["6x2x2", "9x2x2"])
@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.name)
@pytest.mark.parametrize("settings", SETTINGS, ids=["E", "E_regions"])
def test_preset_equals_the_beam_class(mesh, scenario, settings):
    spec = ModelSpec(mesh, scenario, 3, 3, settings)
    old, new = make_model(spec), make_preset(spec)
    assert new.parameters == old.parameters
    theta = np.array(old.parameters.default) * 1.3
    u_old, u_new = old.reset(), new.reset()
    for k in range(1, 4):
        u_old, u_new = old.step(theta, k, u_old), new.step(theta, k, u_new)
        ref = old.displacement_field(u_old)
        scale = np.abs(ref).max()
        np.testing.assert_allclose(
            new.displacement_field(u_new), ref, rtol=0, atol=1e-10 * scale
        )
    tol = 1e-10 * scale
    np.testing.assert_allclose(new.observe(u_new), old.observe(u_old), atol=tol)
    np.testing.assert_allclose(new.grid(u_new), old.grid(u_old), atol=tol)
    a, b = old.probes(u_old), new.probes(u_new)
    assert set(a) == set(b) == {"tip_x", "tip_y", "tip_z"}
    np.testing.assert_allclose([b[n] for n in a], list(a.values()), atol=tol)
    s_old, s_new = old.sensitivity(theta, 3, u_old), new.sensitivity(theta, 3, u_new)
    np.testing.assert_allclose(s_new, s_old, rtol=0, atol=1e-10 * np.abs(s_old).max())


def _oracle_solution(points, tets, fixed, traction, n_steps, E, nu):
    """Displacements (N, 3) after each step by Newton on the scikit-fem forms."""
    from skfem import (
        Basis,
        ElementTetP1,
        ElementVector,
        FacetBasis,
        LinearForm,
        MeshTet,
    )
    from skfem import asm as assemble

    from tests.oracles import svk_forms

    mesh = MeshTet(np.ascontiguousarray(points.T), np.ascontiguousarray(tets.T))
    element = ElementVector(ElementTetP1())
    end = mesh.facets_satisfying(lambda x: x[0] > points[:, 0].max() - 1e-9)
    t = np.asarray(traction)

    @LinearForm
    def load(v, w):  # type: ignore[no-untyped-def]
        return t[0] * v[0] + t[1] * v[1] + t[2] * v[2]

    f_full = assemble(load, FacetBasis(mesh, element, facets=end))
    dofs = Basis(mesh, element).nodal_dofs  # (3, N)
    free = np.setdiff1d(np.arange(len(points)), fixed)
    f = f_full[dofs[:, free].T.ravel()]
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
    model = make_preset(spec)
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
