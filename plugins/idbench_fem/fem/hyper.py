r"""The Galerkin-projected, hyper-reduced internal force and tangent of a body.

A reduced model approximates the free displacements by u = V q, V (n x r) a
basis with orthonormal columns (:mod:`~.pod`), and solves the Galerkin system
V^T f_int(V q; theta) = V^T f_ext. Both laws are linear in each element's
modulus theta_{r(e)} c_e, so with a weight w_e per sampled element
(:mod:`~.ecsw`; every element with weight 1 is the exact projection)

.. math::

    \hat f(q; \theta) = \sum_\rho \theta_\rho \hat g_\rho(q),\qquad
    \hat g_\rho(q) = \sum_{e \in \rho} w_e c_e\, V_e^T f_e^{1}(V_e q),

    \hat K(q; \theta) = \sum_\rho \theta_\rho \hat K_\rho(q),\qquad
    \hat K_\rho(q) = \sum_{e \in \rho} w_e c_e\, V_e^T K_e^{1}(V_e q)\, V_e,

where V_e (12 x r) are the rows of V at element e's dofs (zero at fixed dofs)
and f_e^1, K_e^1 the element force and tangent at unit modulus. K-hat is the
exact derivative of f-hat (the same weighted sum), symmetric, and positive
definite wherever every sampled element's tangent is: Newton on q keeps the
full model's convergence. Each region's g-hat and K-hat are kept apart, so
theta stays exact, one tangent evaluation serves every theta, and the
sensitivity is one reduced solve, dq/dtheta_rho = -K-hat^-1 g-hat_rho.

Two paths, equal to round-off: with numba (:func:`~.kernels.available`) the
sampled elements of each region form a compact mesh of their own dofs,
lifted by the rows V_c of V there (u_c = V_c q), and the compiled loops of
the assemblers (:mod:`~.law_kernels`) give F, S, det F and the compact
internal force in one pass (g-hat_rho = V_c^T f_c) and the element tangents;
otherwise the numpy kernels of :mod:`~.element_set`. One evaluation costs
O(T_s r) (the force) and O(T_s 12 r^2) (the tangent) for T_s sampled
elements: it does not depend on the fine mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench_fem.fem import kernels, law_kernels
from idbench_fem.fem.element_set import ElementSet

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class Evaluation:
    """The sampled elements at one q: det F (T_s,) and g-hat (r, p).

    ``parts`` holds what the tangent needs (per region).
    """

    det: FloatArray
    g: FloatArray
    parts: list[Any] = field(default_factory=list)

    @property
    def valid(self) -> bool:
        """No sampled element inverted, and a finite force."""
        return bool(np.all(self.det > 0) and np.all(np.isfinite(self.g)))


@dataclass
class _Block:
    """One region's sampled elements as a compact mesh of their own dofs."""

    members: IntArray  # positions among the sampled elements
    dofs: IntArray  # (T_b, 12) compact dofs, -1 fixed
    V: FloatArray  # (n_b, r) rows of V at the compact dofs
    Ve: FloatArray  # (T_b, 12, r)
    grads: FloatArray
    volumes: FloatArray
    unit: FloatArray  # w_e c_e
    emap: IntArray  # (T_b, 144): element matrix e, entry j -> 144 e + j
    n: int  # compact dofs


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
    compiled
        Use the compiled loops; None: where numba works.
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
        compiled: bool | None = None,
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
        self.p = int(p)
        self._ve = Ve
        self._vflat = Ve.reshape(T * 12, self.r)
        self._regions = np.asarray(regions, dtype=np.int64)
        self._unit = np.asarray(weights, float) * np.asarray(factors, float)
        self._onehot = (self._regions[:, None] == np.arange(p)).astype(float)
        self._members = [np.flatnonzero(self._regions == rho) for rho in range(p)]
        code = law_kernels.LAW_CODES.get(elements.law, -1)
        if compiled is None:
            compiled = kernels.available()
        self.compiled = bool(compiled) and code >= 0
        """Whether the compiled loops are used (else numpy)."""
        self._code = code
        self._blocks = [self._block(m, dofs, V) for m in self._members]
        self._parts = [elements.subset(m) for m in self._members]

    def _block(self, members: IntArray, dofs: IntArray, V: FloatArray) -> _Block:
        d = dofs[members]
        used = np.unique(d[d >= 0])
        compact = np.full(d.shape, -1, dtype=np.int64)
        held = d >= 0
        compact[held] = np.searchsorted(used, d[held])
        T_b = len(members)
        return _Block(
            members, compact, np.ascontiguousarray(V[used]),
            np.ascontiguousarray(self._ve[members]),
            np.ascontiguousarray(self.elements.grads[members]),
            np.ascontiguousarray(self.elements.volumes[members]),
            np.ascontiguousarray(self._unit[members]),
            np.arange(T_b * 144, dtype=np.int64).reshape(T_b, 144), len(used),
        )  # fmt: skip

    @property
    def n_elements(self) -> int:
        """Sampled elements T_s."""
        return len(self.elements)

    def evaluate(self, q: FloatArray) -> Evaluation:
        """The sampled elements at reduced coordinates ``q`` (r,): det F and g-hat."""
        q = np.asarray(q, dtype=np.float64)
        if not self.compiled:
            st = self.elements.state((self._vflat @ q).reshape(-1, 4, 3))
            fe = self.elements.forces(st, self._unit)  # (T_s, 12)
            g = np.einsum("tir,ti->tr", self._ve, fe).T @ self._onehot
            return Evaluation(st.det, np.asarray(g), [st])
        det = np.empty(self.n_elements)
        g = np.empty((self.r, self.p))
        parts = []
        el = self.elements
        for rho, b in enumerate(self._blocks):
            T_b = len(b.members)
            F, S = np.empty((T_b, 3, 3)), np.empty((T_b, 3, 3))
            d, force = np.empty(T_b), np.zeros(b.n)
            kernels.loops().law_kinematics(self._code, b.V @ q, b.unit, b.dofs,
                                           b.grads, b.volumes, el.lam, el.mu, F, S,
                                           d, force)  # fmt: skip
            det[b.members] = d
            g[:, rho] = b.V.T @ force
            parts.append((F, S, d))
        return Evaluation(det, g, parts)

    def force(self, ev: Evaluation, theta: FloatArray) -> FloatArray:
        """f-hat (r,) = sum_rho theta_rho g-hat_rho."""
        return np.asarray(ev.g @ np.asarray(theta, dtype=float))

    def tangent(self, ev: Evaluation, theta: FloatArray) -> FloatArray:
        """K-hat (r, r) at parameters ``theta``."""
        return np.asarray(np.tensordot(theta, self.region_tangents(ev), axes=1))

    def region_tangents(self, ev: Evaluation) -> FloatArray:
        """Each region's reduced tangent at unit modulus (p, r, r), symmetric.

        K-hat(q; theta) = sum_rho theta_rho K-hat_rho(q): one evaluation serves
        every theta at this state.
        """
        out = np.empty((self.p, self.r, self.r))
        el = self.elements
        for rho, b in enumerate(self._blocks):
            T_b = len(b.members)
            if self.compiled:
                F, S, d = ev.parts[rho]
                data = np.zeros(T_b * 144)
                kernels.loops().law_tangent(self._code, F, S, d, b.unit, b.grads,
                                            b.volumes, el.lam, el.mu, b.emap,
                                            data)  # fmt: skip
                Ke = data.reshape(T_b, 12, 12)
            else:
                (st,) = ev.parts
                Ke = self._parts[rho].tangents(st.take(b.members), b.unit)
            A = np.matmul(Ke, b.Ve).reshape(-1, self.r)
            K = b.Ve.reshape(-1, self.r).T @ A
            out[rho] = 0.5 * (K + K.T)
        return out
