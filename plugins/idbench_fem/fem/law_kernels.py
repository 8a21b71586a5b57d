r"""Compiled kernels of the general-law assembly (numba, optional).

The compiled counterpart of :class:`idbench_fem.fem.law_assembly.LawAssembler`'s
numpy path, for every law of :mod:`idbench_fem.fem.materials`:

- :func:`law_kinematics`: one pass over the tets gives F = I + H, det F, the
  second Piola-Kirchhoff stress S = E_e S_1(F) and the assembled internal
  force f_a = V F S G_a on the free dofs;
- :func:`law_tangent`: one pass gives each element's 12 x 12 tangent and
  scatter-adds it into the CSR data of the fixed pattern through a map built
  once (:func:`scatter_map`), so no sparse matrix is built per iteration.

Per element (one quadrature point, G_a the shape-function gradients, V the
volume, m the element's modulus, lambda and mu at unit modulus) the tangent
of both laws has the form

.. math::

    K_{ai,bk} = V m \left[\lambda\, w_{a,i} w_{b,k} + \beta\, w_{b,i} w_{a,k}
        + \beta\, X_{ik}\, h_{ab} \right] + V \delta_{ik}\, G_a \cdot S G_b

- St Venant-Kirchhoff: w_a = F G_a, beta = mu, X = F F^T, h_ab = G_a . G_b;
- neo-Hookean: w_a = F^{-T} G_a, beta = mu - lambda ln J, X = I,
  h_ab = G_a . C^{-1} G_b,

which is B^T D B + (G S G^T) x I of the Mandel form with the law's tangent
(contracting C^{-1} with F: F C^{-1} = F^{-T}, F C^{-1} F^T = I). F^{-1} is
the closed-form adjugate over det F, C^{-1} = F^{-1} F^{-T}; no
``numpy.linalg`` call. The loops are in :mod:`~.element_loops`, with the
per-element steps they share with the beam's kernel. Where det F <= 0 the
neo-Hookean results are NaN, as the numpy path's (a Newton step treats them
as failed).

The numpy path stays the reference and the fallback (equal to round-off,
tests/fem/test_law_kernels.py): it is used without numba, when it does not
import, or with ``IDBENCH_NUMBA=0`` (:func:`idbench_fem.fem.kernels.available`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from idbench_fem.fem.kernels import Elements, loops

if TYPE_CHECKING:
    from idbench_fem.fem.svk_assembly import Kinematics

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

LAW_CODES = {"svk": 0, "neo-hookean": 1}
"""The laws the kernels know, by name, and their code in the loops."""


def law_kinematics(
    code: int, state: FloatArray, modulus: FloatArray, elements: Elements
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """F, S (T, 3, 3), det F (T,) and the internal force (n,) at one state.

    Parameters
    ----------
    code
        The law's code (:data:`LAW_CODES`).
    state
        Free displacements (n,).
    modulus
        Young's modulus per element (T,).
    elements
        The mesh's dofs, gradients, volumes and Lamé parameters.
    """
    u = np.ascontiguousarray(state, dtype=np.float64)
    if u.shape != (elements.n_free,):
        raise ValueError(
            f"state has shape {np.shape(state)}, expected ({elements.n_free},)"
        )
    T = len(elements.element_dofs)
    mod = np.ascontiguousarray(modulus, dtype=np.float64)
    F = np.empty((T, 3, 3))
    S = np.empty((T, 3, 3))
    det = np.empty(T)
    force = np.zeros(elements.n_free)
    loops().law_kinematics(code, u, mod, elements.element_dofs, elements.grads,
                           elements.volumes, elements.lam, elements.mu, F, S, det,
                           force)  # fmt: skip
    return F, S, det, force


def law_tangent(
    code: int,
    kin: Kinematics,
    modulus: FloatArray,
    elements: Elements,
    emap: IntArray,
    nnz: int,
) -> FloatArray:
    """CSR data (nnz,) of the tangent at ``kin`` (from :func:`law_kinematics`).

    ``emap`` (T, 144) is the position in the data of each element matrix
    entry (row-major, dofs ordered (node, component)), -1 where it is not
    stored (a fixed dof, or the lower triangle of an upper pattern).
    """
    data = np.zeros(nnz)
    mod = np.ascontiguousarray(modulus, dtype=np.float64)
    loops().law_tangent(code, kin.F, kin.S, kin.det, mod, elements.grads,
                        elements.volumes, elements.lam, elements.mu, emap,
                        data)  # fmt: skip
    return data


def scatter_map(src: IntArray, pos: IntArray, n_elements: int) -> IntArray:
    """The (T, 144) map of :func:`law_tangent` from a pattern's COO -> CSR pairs.

    ``src`` are the kept entries' flat indices into the (T, 12, 12) element
    matrices, ``pos`` their positions in the CSR data.
    """
    emap = np.full(n_elements * 144, -1, dtype=np.int64)
    emap[src] = pos
    return emap.reshape(n_elements, 144)
