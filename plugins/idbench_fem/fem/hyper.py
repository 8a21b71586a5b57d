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

Springs on the surface (Robin supports, :mod:`~.springs`) are linear in u
and in their stiffness: their reduced matrices M_c = V^T S_c V (r x r) are
exact, with no sampling. A channel whose stiffness is parameter j adds
M_c q to g-hat's column j and M_c to K-hat_j; a known one adds k_c M_c q to
the force and k_c M_c to the tangent whatever theta (:class:`Springs`).

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
    fixed: FloatArray | float = 0.0
    """The known springs' reduced force sum_c k_c M_c q (r,), or 0."""

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


@dataclass(frozen=True)
class Springs:
    """Reduced spring channels: exact, linear in u and in their stiffness.

    Attributes
    ----------
    matrices
        M_c = V^T S_c V, (q, r, r).
    index
        (q,): the parameter of each channel, -1 where its stiffness is known.
    known
        (q,): each known channel's stiffness (ignored where a parameter).
    """

    matrices: FloatArray
    index: IntArray
    known: FloatArray

    @classmethod
    def project(
        cls, matrices: list[Any], index: list[int], known: list[float],
        basis: FloatArray,
    ) -> Springs:  # fmt: skip
        """M_c = V^T S_c V of sparse S_c (n, n) on a basis V (n, r)."""
        V = np.asarray(basis, dtype=np.float64)
        reduced = [V.T @ np.asarray(S @ V) for S in matrices]
        M = np.array([0.5 * (m + m.T) for m in reduced]).reshape(-1, V.shape[1],
                                                                 V.shape[1])
        return cls(M, np.asarray(index, dtype=np.int64),
                   np.nan_to_num(np.asarray(known, dtype=np.float64)))  # fmt: skip

    @property
    def constant(self) -> FloatArray:
        """Sum of k_c M_c over the known channels (r, r)."""
        held = self.index < 0
        return np.asarray(np.tensordot(self.known[held], self.matrices[held], axes=1))


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
        Number of parameters (the moduli's regions, then the springs' own).
    compiled
        Use the compiled loops; None: where numba works.
    springs
        The body's spring channels reduced on the same basis, or None.
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
        springs: Springs | None = None,
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
        self.springs = springs
        identified = 0 if springs is None else int(np.sum(springs.index >= 0))
        n_regions = self.p - identified  # the moduli's; springs' parameters after
        self.fixed_tangent: FloatArray | float = (
            0.0 if springs is None else springs.constant
        )
        """The known springs' reduced tangent (r, r), or 0."""
        self._ve = Ve
        self._vflat = Ve.reshape(T * 12, self.r)
        self._regions = np.asarray(regions, dtype=np.int64)
        self._unit = np.asarray(weights, float) * np.asarray(factors, float)
        self._onehot = (self._regions[:, None] == np.arange(self.p)).astype(float)
        self._members = [
            np.flatnonzero(self._regions == rho) for rho in range(n_regions)
        ]
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
            return self._with_springs(Evaluation(st.det, np.asarray(g), [st]), q)
        det = np.empty(self.n_elements)
        g = np.zeros((self.r, self.p))
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
        return self._with_springs(Evaluation(det, g, parts), q)

    def _with_springs(self, ev: Evaluation, q: FloatArray) -> Evaluation:
        """``ev`` with the springs' M_c q in g-hat's columns or its fixed force."""
        sp = self.springs
        if sp is None or not len(sp.index):
            return ev
        forces = sp.matrices @ q  # (q, r)
        for c, j in enumerate(sp.index):
            if j >= 0:
                ev.g[:, j] += forces[c]
        held = sp.index < 0
        ev.fixed = forces[held].T @ sp.known[held]
        return ev

    def force(self, ev: Evaluation, theta: FloatArray) -> FloatArray:
        """f-hat (r,) = sum_rho theta_rho g-hat_rho (+ the known springs')."""
        return np.asarray(ev.g @ np.asarray(theta, dtype=float) + ev.fixed)

    def tangent(self, ev: Evaluation, theta: FloatArray) -> FloatArray:
        """K-hat (r, r) at parameters ``theta``."""
        return self.combine(self.region_tangents(ev), theta)

    def combine(self, tangents: FloatArray, theta: FloatArray) -> FloatArray:
        """sum_rho theta_rho K-hat_rho + the known springs' (r, r)."""
        return np.asarray(np.tensordot(theta, tangents, axes=1) + self.fixed_tangent)

    def region_tangents(self, ev: Evaluation) -> FloatArray:
        """Each region's reduced tangent at unit modulus (p, r, r), symmetric.

        K-hat(q; theta) = sum_rho theta_rho K-hat_rho(q): one evaluation serves
        every theta at this state.
        """
        out = np.zeros((self.p, self.r, self.r))
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
        sp = self.springs
        for c, j in enumerate(() if sp is None else sp.index):
            if j >= 0:
                out[j] += sp.matrices[c]  # type: ignore[union-attr]
        return out
