r"""The Galerkin-projected, hyper-reduced internal force and tangent of a body.

A reduced model approximates the free displacements by u = V q, V (n x r) a
basis with orthonormal columns (:mod:`~.pod`), and solves the Galerkin system
V^T f_int(V q; theta) = V^T f_ext. Both laws are linear in each element's
modulus theta_{r(e)} c_e, so with a weight w_e per sampled element
(:mod:`~.ecsw`; every element with weight 1 is the exact projection)

.. math::

    \hat f(q; \theta) = \sum_\rho \theta_\rho \hat g_\rho(q),\qquad
    \hat g_\rho(q) = \sum_{e \in \rho} w_e c_e\, V_e^T f_e^{1}(V_e q),

    \hat K(q; \theta) = \sum_e w_e c_e \theta_{\rho(e)}\, V_e^T K_e^{1}(V_e q)\, V_e,

where V_e (12 x r) are the rows of V at element e's dofs (zero at fixed dofs)
and f_e^1, K_e^1 the element force and tangent at unit modulus
(:mod:`~.element_set`). K-hat is the exact derivative of f-hat (the same
weighted sum), symmetric, and positive definite wherever every sampled
element's tangent is: Newton on q keeps the full model's convergence. Each
region's force g-hat_rho is kept apart, so theta stays exact and the
sensitivity is one reduced solve, dq/dtheta_rho = -K-hat^-1 g-hat_rho.

The cost of one evaluation is O(T_s (12 r + 12^2 r + 12 r^2)) for T_s sampled
elements: it does not depend on the fine mesh.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from idbench_fem.fem.element_set import ElementSet, ElementState

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class HyperReduced:
    """Reduced force and tangent on sampled elements (see the module).

    Parameters
    ----------
    elements
        The sampled elements' geometry and law (T_s elements).
    element_dofs
        Their free-dof indices (T_s, 12), -1 at a fixed dof.
    basis
        V (n, r), the reduced basis on the free dofs.
    weights
        w_e (T_s,), >= 0 (all 1 with every element: the exact projection).
    factors
        c_e (T_s,), each element's modulus over its region's parameter.
    regions
        Each element's parameter region (T_s,), in 0..p-1.
    p
        Number of parameters.
    """

    def __init__(
        self,
        elements: ElementSet,
        element_dofs: IntArray,
        basis: FloatArray,
        weights: FloatArray,
        factors: FloatArray,
        regions: IntArray,
        p: int,
    ) -> None:
        T = len(elements)
        dofs = np.asarray(element_dofs, dtype=np.int64)
        if dofs.shape != (T, 12):
            raise ValueError(f"element_dofs has shape {dofs.shape}, expected ({T}, 12)")
        if np.any(np.asarray(weights) < 0):
            raise ValueError("element weights must be >= 0")
        V = np.asarray(basis, dtype=np.float64)
        self.r = V.shape[1]
        Ve = np.zeros((T, 12, self.r))
        held = dofs >= 0
        Ve[held] = V[dofs[held]]
        self.elements = elements
        self._ve = Ve
        self._vflat = Ve.reshape(T * 12, self.r)
        self._regions = np.asarray(regions, dtype=np.int64)
        self._unit = np.asarray(weights, float) * np.asarray(factors, float)
        self._onehot = (self._regions[:, None] == np.arange(p)).astype(float)
        self.p = int(p)

    @property
    def n_elements(self) -> int:
        """Sampled elements T_s."""
        return len(self.elements)

    def state(self, q: FloatArray) -> ElementState:
        """The sampled elements' kinematics at reduced coordinates ``q`` (r,)."""
        ue = (self._vflat @ np.asarray(q, dtype=np.float64)).reshape(-1, 4, 3)
        return self.elements.state(ue)

    def modulus(self, theta: FloatArray) -> FloatArray:
        """w_e c_e theta_{r(e)} (T_s,): the weighted moduli of the sampled elements."""
        return np.asarray(self._unit * np.asarray(theta)[self._regions])

    def region_forces(self, st: ElementState) -> FloatArray:
        """g-hat (r, p): each region's reduced internal force at unit modulus."""
        fe = self.elements.forces(st, self._unit)  # (T_s, 12)
        proj = np.einsum("tir,ti->tr", self._ve, fe)
        return np.asarray(proj.T @ self._onehot)

    def force(self, st: ElementState, theta: FloatArray) -> FloatArray:
        """f-hat (r,) = sum_rho theta_rho g-hat_rho."""
        return np.asarray(self.region_forces(st) @ np.asarray(theta, dtype=float))

    def tangent(self, st: ElementState, theta: FloatArray) -> FloatArray:
        """K-hat (r, r) at parameters ``theta``."""
        Ke = self.elements.tangents(st, self.modulus(theta))
        A = np.matmul(Ke, self._ve).reshape(-1, self.r)
        K = self._vflat.T @ A
        return np.asarray(0.5 * (K + K.T))
