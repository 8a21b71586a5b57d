r"""Test oracle: the SVK residual and tangent as scikit-fem forms.

Slow but obviously right: :class:`skfem.LinearForm` and
:class:`skfem.BilinearForm` on ``ElementVector(ElementTetP1())`` with a
one-point rule, written from the continuum expressions

.. math::

    r(v) = \int P(F) : \nabla v, \qquad
    a(du, v) = \int (\nabla du\, S + F\, \delta S) : \nabla v,
    \quad \delta S = \lambda\, \mathrm{tr}(\delta E) I + 2 \mu\, \delta E,
    \quad \delta E = \mathrm{sym}(F^T \nabla du).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def _basis(points: FloatArray, tets: NDArray[np.int64]):  # type: ignore[no-untyped-def]
    from skfem import Basis, ElementTetP1, ElementVector, MeshTet

    mesh = MeshTet(np.ascontiguousarray(points.T), np.ascontiguousarray(tets.T))
    return Basis(mesh, ElementVector(ElementTetP1()), intorder=1)


def _full_dofs(basis, free_nodes: NDArray[np.int64]) -> NDArray[np.int64]:  # type: ignore[no-untyped-def]
    """Skfem dof indices of the free nodes, ordered (node, component)."""
    return np.asarray(basis.nodal_dofs[:, free_nodes].T.ravel())


def residual_and_tangent(
    points: FloatArray,
    tets: NDArray[np.int64],
    free_nodes: NDArray[np.int64],
    displacement: FloatArray,
    modulus: FloatArray,
    nu: float,
) -> tuple[FloatArray, sp.csr_matrix]:
    """Assemble internal force and tangent on the free dofs (node-major).

    Parameters
    ----------
    points, tets
        Mesh (N, 3), (T, 4).
    free_nodes
        Indices of the unconstrained nodes, increasing.
    displacement
        All nodal displacements (N, 3).
    modulus
        Young's modulus per element (T,).
    nu
        Poisson's ratio.
    """
    from skfem import BilinearForm, LinearForm, asm
    from skfem.helpers import ddot, eye, grad, mul, trace, transpose

    basis = _basis(points, tets)
    lam = nu / ((1 + nu) * (1 - 2 * nu))
    mu = 1.0 / (2 * (1 + nu))
    u = np.zeros(basis.N)
    u[basis.nodal_dofs.T.ravel()] = displacement.ravel()
    u_field = basis.interpolate(u)
    # one value per element and quadrature point
    emod_field = np.broadcast_to(modulus[:, None], (len(tets), basis.X.shape[1]))

    def kin(w):  # type: ignore[no-untyped-def]
        H = grad(w["u"])
        one = eye(np.ones_like(H[0, 0]), 3)
        F = one + H
        E = 0.5 * (H + transpose(H) + mul(transpose(H), H))
        S = w["E"] * (lam * trace(E) * one + 2 * mu * E)
        return F, S, one

    @LinearForm
    def residual(v, w):  # type: ignore[no-untyped-def]
        F, S, _ = kin(w)
        return ddot(mul(F, S), grad(v))

    @BilinearForm
    def tangent(du, v, w):  # type: ignore[no-untyped-def]
        F, S, one = kin(w)
        dE = 0.5 * (mul(transpose(F), grad(du)) + mul(transpose(grad(du)), F))
        dS = w["E"] * (lam * trace(dE) * one + 2 * mu * dE)
        return ddot(mul(grad(du), S) + mul(F, dS), grad(v))

    r = asm(residual, basis, u=u_field, E=emod_field)
    K = asm(tangent, basis, u=u_field, E=emod_field)
    dofs = _full_dofs(basis, free_nodes)
    return r[dofs], K[dofs][:, dofs].tocsr()


def end_traction(
    points: FloatArray, tets: NDArray[np.int64], traction: FloatArray
) -> FloatArray:
    """Nodal forces (N, 3) of a uniform ``traction`` on the end face x = max x."""
    from skfem import FacetBasis, LinearForm, asm

    basis = _basis(points, tets)
    end = basis.mesh.facets_satisfying(lambda x: x[0] > points[:, 0].max() - 1e-9)
    t = np.asarray(traction)

    @LinearForm
    def load(v, w):  # type: ignore[no-untyped-def]
        return t[0] * v[0] + t[1] * v[1] + t[2] * v[2]

    f = asm(load, FacetBasis(basis.mesh, basis.elem, facets=end))
    return np.asarray(f[basis.nodal_dofs.T.ravel()].reshape(-1, 3))


def linear_solution(
    points: FloatArray,
    tets: NDArray[np.int64],
    clamped: NDArray[np.int64],
    nodal_force: FloatArray,
    young: float,
    nu: float,
) -> FloatArray:
    """Linear-elasticity displacements (N, 3) with scikit-fem's own model.

    ``nodal_force`` (N, 3) is the load; ``clamped`` nodes are fixed.
    """
    from skfem import asm, condense, solve
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    basis = _basis(points, tets)
    K = asm(linear_elasticity(*lame_parameters(young, nu)), basis)
    f = np.zeros(basis.N)
    f[basis.nodal_dofs.T.ravel()] = nodal_force.ravel()
    fixed = basis.nodal_dofs[:, clamped].ravel()
    x = solve(*condense(K, f, D=fixed))
    return np.asarray(x[basis.nodal_dofs.T.ravel()].reshape(-1, 3))
