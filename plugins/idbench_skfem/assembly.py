r"""Vectorised St Venant-Kirchhoff kernels and sparse assembly for P1 tetrahedra.

With one quadrature point per element the shape-function gradients
:math:`G_{aJ} = \partial N_a / \partial X_J` are constant, so for every element
(all at once, with ``einsum``):

.. math::

    H = \sum_a u_a \otimes G_a,\quad F = I + H,\quad
    E = \tfrac12 (H + H^T + H^T H),\quad
    S = \lambda\, \mathrm{tr}(E) I + 2 \mu E,\quad P = F S,

    f_{ai} = V P_{iJ} G_{aJ},

    K_{aibk} = V \left[\lambda Q_{ai} Q_{bk} + \mu (F F^T)_{ik} (G_a \cdot G_b)
               + \mu Q_{ak} Q_{bi} + (G_a S G_b)\, \delta_{ik}\right],
    \quad Q_{ai} = F_{iJ} G_{aJ}.

Both are linear in the element's Young's modulus, which is what makes the
sensitivity du/dE = -K^-1 g(u) cheap. The sparsity pattern of the free-free
tangent and the scatter from element matrices to its CSR data are built once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def lame_unit(nu: float) -> tuple[float, float]:
    """Lamé parameters (lambda, mu) at unit Young's modulus."""
    if not -1.0 < nu < 0.5:
        raise ValueError(f"nu = {nu!r}: Poisson's ratio must be in (-1, 0.5)")
    return nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), 1.0 / (2.0 * (1.0 + nu))


def shape_gradients(
    points: FloatArray, tets: NDArray[np.int64]
) -> tuple[FloatArray, FloatArray]:
    """P1 shape-function gradients (T, 4, 3) and volumes (T,) of every tet."""
    x = points[tets]
    jac = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
    inv = np.linalg.inv(jac)  # rows: gradients of the barycentric coords 1..3
    grads = np.empty((len(tets), 4, 3))
    grads[:, 1:] = inv
    grads[:, 0] = -inv.sum(axis=1)
    return grads, np.abs(np.linalg.det(jac)) / 6.0


@dataclass
class Kinematics:
    """Per-element state at one displacement, shapes (T, 3, 3) and (T,)."""

    F: FloatArray
    S: FloatArray
    det: FloatArray


@dataclass(frozen=True)
class Pattern:
    """CSR pattern of the free-free tangent and the scatter that fills it.

    Attributes
    ----------
    indptr, indices
        CSR structure, n x n; only the upper triangle when ``upper``.
    scatter
        Sparse (nnz, T * 144): CSR data = scatter @ element_matrices.ravel().
    upper
        Whether only the upper triangle (row <= col) is stored.
    """

    indptr: NDArray[np.int32]
    indices: NDArray[np.int32]
    scatter: sp.csr_matrix
    upper: bool

    @property
    def nnz(self) -> int:
        """Number of stored entries."""
        return len(self.indices)

    def matvec(self, data: FloatArray, x: FloatArray) -> FloatArray:
        """Product of the full symmetric matrix with CSR ``data`` and ``x`` (n, k)."""
        n = len(self.indptr) - 1
        a = sp.csr_matrix((data, self.indices, self.indptr), shape=(n, n))
        y = a @ x
        if self.upper:
            y += a.T @ x
            y -= a.diagonal().reshape((n,) + (1,) * (x.ndim - 1)) * x
        return np.asarray(y)

    def matrix(self, data: FloatArray) -> sp.csr_matrix:
        """Return the full symmetric matrix with CSR ``data`` (tests, scipy)."""
        n = len(self.indptr) - 1
        a = sp.csr_matrix((data, self.indices, self.indptr), shape=(n, n))
        if self.upper:
            a = a + sp.triu(a, k=1).T
        return a.tocsr()


class Assembler:
    """Internal forces and tangents of the SVK beam on the free degrees of freedom.

    Parameters
    ----------
    points, tets
        The mesh, (N, 3) and (T, 4), tets positively oriented.
    free
        Boolean mask (N,) of the unconstrained nodes.
    nu
        Poisson's ratio.

    Notes
    -----
    The free degrees of freedom are numbered node-major, ``3 * j + c`` for the
    j-th free node and component c.
    """

    def __init__(
        self,
        points: FloatArray,
        tets: NDArray[np.int64],
        free: NDArray[np.bool_],
        nu: float,
    ) -> None:
        self.n_nodes = len(points)
        self.n_elements = len(tets)
        self.tets = tets
        self.grads, self.volumes = shape_gradients(points, tets)
        self.lam, self.mu = lame_unit(nu)
        node_dof = np.full(self.n_nodes, -1, dtype=np.int64)
        node_dof[free] = 3 * np.arange(int(free.sum()))
        self.n_free = 3 * int(free.sum())
        # full dof index -> free dof index (or -1)
        self.full_to_free = (node_dof[:, None] + np.arange(3)).ravel()
        self.full_to_free[np.repeat(~free, 3)] = -1
        self.free_dofs = np.flatnonzero(self.full_to_free >= 0)
        self.element_dofs = self.full_to_free[
            (3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)
        ]
        ed = self.element_dofs.ravel()
        keep = ed >= 0
        self._force_scatter = sp.csr_matrix(
            (np.ones(int(keep.sum())), (ed[keep], np.flatnonzero(keep))),
            shape=(self.n_free, ed.size),
        )
        self._patterns: dict[bool, Pattern] = {}
        self._u_full = np.zeros(3 * self.n_nodes)

    # -- kinematics and forces -------------------------------------------------

    def element_displacements(self, state: FloatArray) -> FloatArray:
        """Nodal displacements per element (T, 4, 3) from the free state (n,)."""
        u = self._u_full
        u[self.free_dofs] = state
        return u.reshape(-1, 3)[self.tets]

    def kinematics(self, state: FloatArray, modulus: FloatArray) -> Kinematics:
        """Deformation gradient, second Piola-Kirchhoff stress and det F.

        Parameters
        ----------
        state
            Free displacements (n,).
        modulus
            Young's modulus per element (T,).
        """
        H = np.matmul(self.element_displacements(state).transpose(0, 2, 1), self.grads)
        Ht = H.transpose(0, 2, 1)
        E = np.matmul(Ht, H)
        E += H
        E += Ht
        E *= 0.5
        tr = E[:, 0, 0] + E[:, 1, 1] + E[:, 2, 2]
        S = (2.0 * self.mu) * E
        idx = np.arange(3)
        S[:, idx, idx] += (self.lam * tr)[:, None]
        S *= modulus[:, None, None]
        F = H
        F[:, idx, idx] += 1.0
        det = (
            F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
            - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
            + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0])
        )
        return Kinematics(F, S, det)

    def element_forces(self, kin: Kinematics) -> FloatArray:
        """Element internal forces (T, 4, 3): V P_iJ G_aJ."""
        P = np.matmul(kin.F, kin.S * self.volumes[:, None, None])
        return np.matmul(self.grads, P.transpose(0, 2, 1))

    def forces(self, kin: Kinematics) -> FloatArray:
        """Assembled internal force on the free dofs (n,)."""
        return self._force_scatter @ self.element_forces(kin).ravel()

    def region_forces(
        self, kin_unit: Kinematics, regions: NDArray[np.int64], p: int
    ) -> FloatArray:
        """Assemble each region's internal force at unit modulus, (n, p): g_r."""
        fe = self.element_forces(kin_unit).reshape(self.n_elements, 12)
        out = np.empty((self.n_free, p))
        for r in range(p):
            out[:, r] = self._force_scatter @ (fe * (regions == r)[:, None]).ravel()
        return out

    # -- tangent ---------------------------------------------------------------

    def element_tangents(self, kin: Kinematics, modulus: FloatArray) -> FloatArray:
        """Element tangent matrices (T, 12, 12), dofs ordered (node, component).

        The material part is ``B^T s B`` with B (T, 7, 12) the variations of E
        in orthonormal Voigt form (shears times sqrt 2) and of tr E, scaled by
        sqrt(2 mu V E) and sqrt(|lambda| V E): one batched matmul. The
        geometric part adds (G_a S G_b) V on i = k.
        """
        G = self.grads
        w = self.volumes * modulus
        n = self.n_elements
        Fs = kin.F * np.sqrt(2.0 * self.mu * w)[:, None, None]
        # Q[t, J, L, a, i] = F_iJ G_aL, scaled by sqrt(2 mu V E)
        Q = Fs.transpose(0, 2, 1)[:, :, None, None, :] * G.transpose(0, 2, 1)[
            :, None, :, :, None
        ]
        B = np.empty((n, 7, 4, 3))  # column, node, component
        for J in range(3):  # normal strains: F_iJ G_aJ
            B[:, 1 + J] = Q[:, J, J]
        for c, (J, L) in enumerate(((0, 1), (0, 2), (1, 2))):  # shears, times sqrt 2
            np.add(Q[:, J, L], Q[:, L, J], out=B[:, 4 + c])
        B[:, 4:7] *= np.sqrt(0.5)
        np.sum(B[:, 1:4], axis=1, out=B[:, 0])  # trace
        B[:, 0] *= np.sqrt(abs(self.lam) / (2.0 * self.mu))
        B = B.reshape(n, 7, 12)
        Bt = np.ascontiguousarray(B.transpose(0, 2, 1))  # matmul is 4x faster
        if self.lam < 0:
            B = B * np.array([-1.0, 1, 1, 1, 1, 1, 1])[:, None]
        K = np.matmul(Bt, B)
        GS = np.matmul(G, kin.S * self.volumes[:, None, None])
        GSG = np.matmul(GS, G.transpose(0, 2, 1))
        K5 = K.reshape(n, 4, 3, 4, 3)
        for i in range(3):
            K5[:, :, i, :, i] += GSG
        return K

    def pattern(self, upper: bool) -> Pattern:
        """Build (once) the CSR pattern and scatter of the free-free tangent."""
        if upper in self._patterns:
            return self._patterns[upper]
        ed = self.element_dofs
        rows = np.broadcast_to(ed[:, :, None], (self.n_elements, 12, 12)).ravel()
        cols = np.broadcast_to(ed[:, None, :], (self.n_elements, 12, 12)).ravel()
        keep = (rows >= 0) & (cols >= 0)
        if upper:
            keep &= rows <= cols
        src = np.flatnonzero(keep)
        key = rows[src] * self.n_free + cols[src]
        uniq, pos = np.unique(key, return_inverse=True)
        r, c = np.divmod(uniq, self.n_free)
        indptr = np.zeros(self.n_free + 1, dtype=np.int64)
        np.cumsum(np.bincount(r, minlength=self.n_free), out=indptr[1:])
        scatter = sp.csr_matrix(
            (np.ones(len(src)), (pos, src)), shape=(len(uniq), rows.size)
        )
        pat = Pattern(indptr.astype(np.int32), c.astype(np.int32), scatter, upper)
        self._patterns[upper] = pat
        return pat

    def tangent_data(
        self, kin: Kinematics, modulus: FloatArray, pattern: Pattern
    ) -> FloatArray:
        """CSR data of the free-free tangent in ``pattern``."""
        return pattern.scatter @ self.element_tangents(kin, modulus).ravel()
