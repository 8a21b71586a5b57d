"""What the solid model gives estimators of fields: adjoints and linearizations.

:class:`FieldMembers` is a mixin of :class:`~idbench_fem.models.solid.SolidModel`
giving it the optional members of :mod:`idbench.core.optional` that batch and
localized estimators use (:class:`idbench.AdjointModel`,
:class:`idbench.LinearObservationModel`, :class:`idbench.SurfaceJacobianModel`,
:class:`idbench.ReactionJacobianModel`,
:class:`idbench.ObservationPointsModel`). Derivatives are at a converged
state of step k (:mod:`idbench_fem.fem.adjoint`): each solve reuses the
factorization of the step just solved there, with one step of iterative
refinement, as :meth:`SolidModel.sensitivity` does.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from idbench_fem.fem.adjoint import node_sums, parameter_matrix

FloatArray = NDArray[np.float64]


class FieldMembers:
    """Mixin: equilibrium products, observation and reaction Jacobians, points."""

    _asm: Any
    _obs: Any
    _factors: FloatArray
    _driven: Any
    element_regions: Any
    marker_points: FloatArray
    n_state: int
    n_nodes: int
    sensitivity_refine: bool

    def _unknowns(self, state: FloatArray) -> FloatArray:
        """The state's unknowns (all of it unless a grasp prescribes some dofs)."""
        u = np.asarray(state, dtype=np.float64)
        if self._driven is None:
            return u
        self._asm.values = u[self._asm.prescribed]
        return np.asarray(u[self._asm.unknown])

    def _parameter_matrix(self, u: FloatArray) -> Any:
        """G (n_unknowns, p) at the unknowns ``u`` (:mod:`idbench_fem.fem.adjoint`)."""
        kin = self._asm.kinematics(u, self._factors)
        asm = self._state_asm()  # type: ignore[attr-defined]
        p = self.parameters.p  # type: ignore[attr-defined]
        G = parameter_matrix(asm, kin, self.element_regions, p)
        return G if self._driven is None else G[self._asm.unknown]

    def _solve(self, theta: FloatArray, k: int, u: FloatArray, rhs: Any) -> Any:
        """K(u)^-1 rhs (n, q), with the step's factorization where it can."""
        modulus = self.element_moduli(theta, k)  # type: ignore[attr-defined]
        dense = np.asarray(rhs.toarray() if sp.issparse(rhs) else rhs, dtype=float)
        return -self._state_sensitivity(  # type: ignore[attr-defined]
            theta, k, u, modulus, dense.reshape(len(u), -1), self.sensitivity_refine
        )

    def equilibrium_jvp(
        self, theta: FloatArray, k: int, state: FloatArray, v: FloatArray
    ) -> FloatArray:
        """(du/dtheta) v = -K^-1 G v: v (p,) -> (n,), or (p, q) -> (n, q)."""
        u = self._unknowns(state)
        v = np.asarray(v, dtype=float)
        G = self._parameter_matrix(u)
        du = -self._solve(theta, k, u, G @ v.reshape(G.shape[1], -1))
        out = du
        if self._driven is not None:  # the tool's dofs do not move with theta
            out = np.zeros((self.n_state, du.shape[1]))
            out[self._asm.unknown] = du
        return np.asarray(out if v.ndim == 2 else out[:, 0])

    def equilibrium_vjp(
        self, theta: FloatArray, k: int, state: FloatArray, w: FloatArray
    ) -> FloatArray:
        """w^T (du/dtheta) = -G^T K^-T w: w (n,) -> (p,), or (n, q) -> (p, q)."""
        u = self._unknowns(state)
        w = np.asarray(w, dtype=float)
        w2 = w.reshape(self.n_state, -1)
        if self._driven is not None:
            w2 = w2[self._asm.unknown]
        lam = self._solve(theta, k, u, w2)  # K symmetric: K^-T = K^-1
        out = -(self._parameter_matrix(u).T @ lam)
        return np.asarray(out if w.ndim == 2 else out[:, 0])

    def observation_jacobian(
        self, theta: FloatArray, k: int, state: FloatArray
    ) -> tuple[Any, FloatArray]:
        """(d observe / d state, zeros): the markers are linear in the state."""
        return sp.csr_matrix(self._obs), np.zeros((self._obs.shape[0], np.size(theta)))

    def observation_points(self, k: int) -> FloatArray:
        """(3M, 3): each marker's undeformed position, once per component."""
        return np.repeat(np.asarray(self.marker_points, dtype=float), 3, axis=0)

    def surface_jacobian(self, state: FloatArray) -> Any:
        """D vec(vertices) / d state (3N, n): every node's, 1 on its free dofs."""
        free = np.asarray(self._state_asm().free_dofs)  # type: ignore[attr-defined]
        return sp.csr_matrix(
            (np.ones(len(free)), (free, np.arange(len(free)))),
            shape=(3 * self.n_nodes, self.n_state),
        )

    def reaction_jacobian(
        self, theta: FloatArray, k: int, state: FloatArray
    ) -> tuple[Any, FloatArray]:
        """D reaction / d state (3, n), sparse, and d reaction / d theta (3, p).

        The reaction sums f_int over a node set S (the grasp's nodes, or the
        fixed ones). On the state's dofs its derivative is e_S^T K (K the
        tangent of all the state's dofs, symmetric); for the fixed nodes,
        outside the state, -e^T K with e all the state's dofs of the
        component (the internal forces of all nodes sum to zero). The theta
        part is each parameter's unit forces summed over S.
        """
        asm = self._state_asm()  # type: ignore[attr-defined]
        u = np.asarray(state, dtype=np.float64)
        modulus = self.element_moduli(theta, None)  # type: ignore[attr-defined]
        p = self.parameters.p  # type: ignore[attr-defined]
        unit = np.asarray(asm.element_forces(asm.kinematics(u, self._factors)))
        _, tets = self.mesh()  # type: ignore[attr-defined]
        on = self._reaction_nodes()[tets]  # type: ignore[attr-defined]
        d_theta = node_sums(unit.reshape(-1, 4, 3), on, self.element_regions, p)
        pattern = asm.pattern(upper=False)
        kin = asm.kinematics(u, modulus)
        K = pattern.matrix(asm.tangent_data(kin, modulus, pattern))
        component = np.asarray(asm.free_dofs) % 3
        if self._driven is None:
            select = np.ones(len(component), dtype=bool)
            sign = -1.0
        else:
            select = np.zeros(len(component), dtype=bool)
            select[self._asm.prescribed] = True
            sign = 1.0
        E = sp.csr_matrix(
            (np.ones(int(select.sum())),
             (component[select], np.flatnonzero(select))),
            shape=(3, len(component)),
        )  # fmt: skip
        return sp.csr_matrix(sign * (E @ K)), d_theta
