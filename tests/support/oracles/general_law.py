r"""Reference: any hyperelastic law on P1 tets, and a plain Newton solve.

Test oracle and prototype for the ``solid`` model, not its hot path. Per
element, with one quadrature point (:mod:`idbench_fem.fem.materials`)

.. math::

    f_e = V B^T s,\qquad K_e = V\,(B^T D B + (G S G^T) \otimes I_3),

B the Mandel strain variation, s = mandel(S), D the Mandel tangent, for a
law evaluated at unit modulus and scaled per element (``linear_in_modulus``).
:func:`solve` ramps a load in K steps and runs Newton with scipy's sparse
direct solver.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl
from numpy.typing import NDArray

from idbench_fem.fem.materials import Material, mandel, strain_variation

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def shape_gradients(
    points: FloatArray, tets: IntArray
) -> tuple[FloatArray, FloatArray]:
    """P1 gradients (T, 4, 3) and signed volumes (T,)."""
    x = points[tets]
    jac = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
    inv = np.linalg.inv(jac)
    grads = np.empty((len(tets), 4, 3))
    grads[:, 1:] = inv
    grads[:, 0] = -inv.sum(axis=1)
    return grads, np.linalg.det(jac) / 6.0


def element_kernel(
    law: Material,
    u: FloatArray,
    tets: IntArray,
    grads: FloatArray,
    volumes: FloatArray,
    modulus: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Element internal forces (T, 12) and tangents (T, 12, 12).

    ``u`` are the nodal displacements (N, 3); dofs ordered (node, component);
    ``law`` is evaluated at unit modulus and scaled by ``modulus`` (T,).
    """
    F = np.eye(3) + np.einsum("tai,taJ->tiJ", u[tets], grads)
    unit = law.with_modulus(1.0)  # type: ignore[attr-defined]
    S = unit.stress(F) * modulus[:, None, None]
    D = unit.mandel_tangent(F) * modulus[:, None, None]
    B = strain_variation(F, grads)
    fe = volumes[:, None] * np.einsum("tab,ta->tb", B, mandel(S))
    Ke = volumes[:, None, None] * np.einsum("tab,tac,tcd->tbd", B, D, B)
    GSG = np.einsum("taI,tIJ,tbJ->tab", grads, S, grads) * volumes[:, None, None]
    Ke.reshape(-1, 4, 3, 4, 3)[:, :, np.arange(3), :, np.arange(3)] += GSG[None]
    return fe, Ke


@dataclass
class Solution:
    """Displacements (N, 3) after the last step, iterations per step, reaction."""

    u: FloatArray
    iterations: list[int]
    internal: FloatArray


def solve(
    law: Material,
    points: FloatArray,
    tets: IntArray,
    modulus: FloatArray,
    fixed: IntArray,
    load: Callable[[float], FloatArray],
    steps: int = 5,
    rtol: float = 1e-10,
    max_iterations: int = 30,
) -> Solution:
    """Ramp ``load(t)`` (nodal forces (N, 3) at fraction t) in ``steps`` steps.

    ``fixed`` nodes have all components zero. ``internal`` is the full
    internal force (N, 3) at the end: on the fixed nodes it is the reaction.

    Raises
    ------
    RuntimeError
        If Newton does not converge in a step.
    """
    grads, volumes = shape_gradients(points, tets)
    dofs = (3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)
    n = 3 * len(points)
    free = np.ones(n, dtype=bool)
    free[(3 * fixed[:, None] + np.arange(3)).ravel()] = False
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, 12).ravel()
    u = np.zeros((len(points), 3))
    iterations = []
    fint = np.zeros(n)
    for k in range(1, steps + 1):
        fext = load(k / steps).ravel()
        scale = max(np.linalg.norm(fext[free]), 1e-300)
        for it in range(max_iterations + 1):
            fe, Ke = element_kernel(law, u, tets, grads, volumes, modulus)
            fint = np.bincount(dofs.ravel(), fe.ravel(), n)
            r = (fint - fext)[free]
            if np.linalg.norm(r) <= rtol * scale:
                break
            if it == max_iterations or not np.isfinite(r).all():
                raise RuntimeError(f"Newton did not converge in step {k}")
            K = sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(n, n))
            u.ravel()[free] -= spl.spsolve(K[free][:, free].tocsc(), r)
        iterations.append(it)
    return Solution(u, iterations, fint.reshape(-1, 3))
