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
sensitivity du/dE = -K^-1 g(u) cheap. The tangent is symmetric, so only its
node-pair blocks :math:`K_{ab}` with a <= b are computed (10 of 16, each 3 x 3,
with :math:`Q_a = F G_a`):

.. math::

    K_{ab} = V E \left[\lambda Q_a \otimes Q_b + \mu Q_b \otimes Q_a
             + \mu (G_a \cdot G_b) F F^T\right] + V (G_a S G_b) I.

The sparsity pattern of the free-free tangent and the scatter from these
blocks to its CSR data are built once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from idbench_fem.fem import kernels

FloatArray = NDArray[np.float64]

CHUNK = 1024
"""Elements per pass of the tangent kernel: its temporaries (10, 3, 3, CHUNK)
then stay in the core's cache (1.5x faster than one pass at 58,000 elements)."""


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
    """Per-element state at one displacement: F and S (T, 3, 3), det F (T,).

    With a leading axis (r, ...) for a stack of states (:class:`Assembler`).
    ``forces`` is the assembled internal force (n,) when a compiled kernel
    (:mod:`idbench_fem.fem.kernels`, :mod:`~.law_kernels`) computed it in the
    same pass, else None.
    """

    F: FloatArray
    S: FloatArray
    det: FloatArray
    forces: FloatArray | None = None


@dataclass(frozen=True)
class Pattern:
    """CSR pattern of the free-free tangent and the scatter that fills it.

    Attributes
    ----------
    indptr, indices
        CSR structure, n x n; only the upper triangle when ``upper``.
    scatter
        Sparse (nnz, 90 T): CSR data = scatter @ blocks.ravel(), blocks the
        (10, 3, 3, T) of :meth:`Assembler.element_tangent_blocks`.
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


class TetAssembly:
    """What both assemblers share: P1 tets with some nodes fixed.

    The geometry (shape-function gradients, volumes), the numbering of the free
    degrees of freedom, node-major (``3 * j + c`` for the j-th free node and
    component c), and the internal forces f_a = V F S G_a from the
    kinematics. :class:`Assembler` (SVK) and
    :class:`idbench_fem.fem.law_assembly.LawAssembler` (any law) add the
    kinematics and the tangent.

    Parameters
    ----------
    points, tets
        The mesh, (N, 3) and (T, 4), tets positively oriented.
    free
        Boolean mask (N,) of the unconstrained nodes.
    lame
        The law's Lamé parameters (lambda, mu) at unit Young's modulus,
        attributes ``lam`` and ``mu`` (the compiled kernels read them, with
        ``element_dofs``, ``grads``, ``volumes`` and ``n_free``).
    """

    def __init__(
        self,
        points: FloatArray,
        tets: NDArray[np.int64],
        free: NDArray[np.bool_],
        lame: tuple[float, float],
    ) -> None:
        self.tets = np.asarray(tets, dtype=np.int64)
        self.n_nodes = len(points)
        self.n_elements = len(tets)
        self.grads, self.volumes = shape_gradients(points, self.tets)
        self.lam, self.mu = lame
        node_dof = np.full(self.n_nodes, -1, dtype=np.int64)
        node_dof[free] = 3 * np.arange(int(free.sum()))
        self.n_free = 3 * int(free.sum())
        # full dof index -> free dof index (or -1)
        self.full_to_free = (node_dof[:, None] + np.arange(3)).ravel()
        self.full_to_free[np.repeat(~free, 3)] = -1
        self.free_dofs = np.flatnonzero(self.full_to_free >= 0)
        self.element_dofs = self.full_to_free[
            (3 * self.tets[:, :, None] + np.arange(3)).reshape(-1, 12)
        ]
        ed = self.element_dofs.ravel()
        keep = ed >= 0
        self._force_scatter = sp.csr_matrix(
            (np.ones(int(keep.sum())), (ed[keep], np.flatnonzero(keep))),
            shape=(self.n_free, ed.size),
        )
        self._patterns: dict[bool, Pattern] = {}
        self._u_full = np.zeros(3 * self.n_nodes)

    def element_forces(self, kin: Kinematics) -> FloatArray:
        """Element internal forces (..., T, 4, 3): V P_iJ G_aJ."""
        P = np.matmul(kin.F, kin.S * self.volumes[:, None, None])
        return np.matmul(self.grads, P.swapaxes(-1, -2))

    def forces(self, kin: Kinematics) -> FloatArray:
        """Assembled internal force on the free dofs, (n,) (or (r, n) for a batch)."""
        if kin.forces is not None:  # the compiled kernel's, computed with kin
            return kin.forces.copy()
        fe = self.element_forces(kin)
        if fe.ndim == 3:
            return self._force_scatter @ fe.ravel()
        return np.asarray(self._force_scatter @ fe.reshape(len(fe), -1).T).T

    def region_forces(
        self, kin_unit: Kinematics, regions: NDArray[np.int64], p: int
    ) -> FloatArray:
        """Each region's internal force g_r (n, p) at the moduli of ``kin_unit``."""
        fe = self.element_forces(kin_unit).reshape(self.n_elements, 12)
        out = np.empty((self.n_free, p))
        for r in range(p):
            out[:, r] = self._force_scatter @ (fe * (regions == r)[:, None]).ravel()
        return out


class Assembler(TetAssembly):
    """Internal forces and tangents of the SVK beam on the free degrees of freedom.

    Parameters
    ----------
    points, tets, free
        As for :class:`TetAssembly`.
    nu
        Poisson's ratio.
    compiled
        Evaluate kinematics and internal forces with the compiled kernel
        (:mod:`idbench_fem.fem.kernels`); None: where numba is installed and
        ``IDBENCH_NUMBA`` is not 0.
    """

    STACKS = True
    """:meth:`kinematics` and :meth:`forces` take a stack of states (r, n)."""

    def __init__(
        self,
        points: FloatArray,
        tets: NDArray[np.int64],
        free: NDArray[np.bool_],
        nu: float,
        compiled: bool | None = None,
    ) -> None:
        super().__init__(points, tets, free, lame_unit(nu))
        self.compiled = kernels.available() if compiled is None else bool(compiled)
        # V G_a . G_b of the node pairs a <= b (T, 10): constant, computed once
        self._pair_a, self._pair_b = np.triu_indices(4)
        gg = np.matmul(self.grads, self.grads.transpose(0, 2, 1))
        self._gg_pairs_t = np.ascontiguousarray(
            (gg[:, self._pair_a, self._pair_b] * self.volumes[:, None]).T
        )  # (10, T)
        self._grads_t = np.ascontiguousarray(self.grads.transpose(1, 2, 0))  # (4,3,T)
        self._block_work = np.empty((10, 3, 3, min(CHUNK, self.n_elements)))
        self._blocks = np.empty((10, 3, 3, self.n_elements))

    # -- kinematics and forces -------------------------------------------------

    def element_displacements(self, state: FloatArray) -> FloatArray:
        """Nodal displacements per element (..., T, 4, 3) from free states (..., n)."""
        if state.ndim == 1:
            u = self._u_full
            u[self.free_dofs] = state
            return u.reshape(-1, 3)[self.tets]
        full = np.zeros((*state.shape[:-1], 3 * self.n_nodes))
        full[..., self.free_dofs] = state
        return full.reshape(*state.shape[:-1], -1, 3)[..., self.tets, :]

    def kinematics(self, state: FloatArray, modulus: FloatArray) -> Kinematics:
        """Deformation gradient, second Piola-Kirchhoff stress and det F.

        Parameters
        ----------
        state
            Free displacements (n,), or a batch (r, n).
        modulus
            Young's modulus per element (T,), or per state (r, T).

        Returns
        -------
        Kinematics
            F and S (T, 3, 3) and det F (T,), or (r, T, 3, 3) and (r, T); with
            the compiled kernel also the internal force.
        """
        if self.compiled:
            F, S, det, f = kernels.svk_kinematics(state, modulus, self)
            return Kinematics(F, S, det, f)
        H = np.matmul(self.element_displacements(state).swapaxes(-1, -2), self.grads)
        Ht = H.swapaxes(-1, -2)
        E = np.matmul(Ht, H)
        E += H
        E += Ht
        E *= 0.5
        tr = E[..., 0, 0] + E[..., 1, 1] + E[..., 2, 2]
        S = (2.0 * self.mu) * E
        idx = np.arange(3)
        S[..., idx, idx] += (self.lam * tr)[..., None]
        S *= modulus[..., None, None]
        F = H
        F[..., idx, idx] += 1.0
        det = (
            F[..., 0, 0] * (F[..., 1, 1] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 1])
            - F[..., 0, 1] * (F[..., 1, 0] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 0])
            + F[..., 0, 2] * (F[..., 1, 0] * F[..., 2, 1] - F[..., 1, 1] * F[..., 2, 0])
        )
        return Kinematics(F, S, det)

    # -- tangent ---------------------------------------------------------------

    def element_tangent_blocks(
        self, kin: Kinematics, modulus: FloatArray, out: FloatArray | None = None
    ) -> FloatArray:
        """Node-pair blocks K_ab for a <= b, shape (10, 3, 3, T), elements last.

        Pair j is ``(a, b) = numpy.triu_indices(4)[.][j]``; entry (j, i, k, t) is
        K[3a + i, 3b + k] of element t. See the module docstring for the maths.
        Elements last, so every numpy operation runs over a contiguous (T,)
        axis, with the two (10, 3, 3, T) temporaries preallocated: about 5x
        faster than a batched matmul of 12 x 12 element matrices.

        Parameters
        ----------
        kin, modulus
            Kinematics at the state and Young's modulus per element (T,).
        out
            Optional output array (10, 3, 3, T).
        """
        K = np.empty((10, 3, 3, self.n_elements)) if out is None else out
        Ft = np.ascontiguousarray(kin.F.transpose(1, 2, 0))  # (3, 3, T)
        SV = kin.S.transpose(1, 2, 0) * self.volumes  # (3, 3, T)
        for lo in range(0, self.n_elements, CHUNK):
            sl = slice(lo, min(lo + CHUNK, self.n_elements))
            self._tangent_chunk(Ft[..., sl], SV[..., sl], modulus[sl], sl, K[..., sl])
        return K

    def _tangent_chunk(
        self,
        Ft: FloatArray,
        SV: FloatArray,
        modulus: FloatArray,
        sl: slice,
        K: FloatArray,
    ) -> None:
        """The blocks of the elements ``sl`` into ``K`` (10, 3, 3, c)."""
        ia, ib = self._pair_a, self._pair_b
        Gt, vol = self._grads_t[..., sl], self.volumes[sl]
        Q = Gt[:, None, 0] * Ft[None, :, 0]  # (4, 3, c): Q_ai = F_iJ G_aJ
        Q += Gt[:, None, 1] * Ft[None, :, 1]
        Q += Gt[:, None, 2] * Ft[None, :, 2]
        Qw = Q * (vol * modulus)
        tmp = self._block_work[..., : K.shape[-1]]
        np.multiply(Q[ia][:, :, None], (self.lam * Qw)[ib][:, None, :], out=K)
        np.multiply(Q[ib][:, :, None], (self.mu * Qw)[ia][:, None, :], out=tmp)
        K += tmp
        FFt = (Ft[:, None] * Ft[None, :]).sum(axis=2)  # (3, 3, c)
        gg = self._gg_pairs_t[:, sl] * (self.mu * modulus)  # (10, c)
        np.multiply(gg[:, None, None], FFt[None], out=tmp)
        K += tmp
        GS = (Gt[:, :, None] * SV[None]).sum(axis=1)  # (4, 3, c): G_aJ S_JL V
        GSG = (GS[ia] * Gt[ib]).sum(axis=1)  # (10, c)
        for i in range(3):
            K[:, i, i] += GSG

    def pattern(self, upper: bool) -> Pattern:
        """Build (once) the CSR pattern and scatter of the free-free tangent."""
        if upper in self._patterns:
            return self._patterns[upper]
        # entry (pair, i, k, t) of the blocks is K[3a + i, 3b + k] of element t
        ed = self.element_dofs.reshape(-1, 4, 3).transpose(1, 2, 0)  # (4, 3, T)
        shape = (10, 3, 3, self.n_elements)
        rows = np.broadcast_to(ed[self._pair_a, :, None, :], shape).ravel()
        cols = np.broadcast_to(ed[self._pair_b, None, :, :], shape).ravel()
        off = np.broadcast_to((self._pair_a < self._pair_b)[:, None, None, None], shape)
        off = off.ravel()
        src = np.arange(rows.size)
        if upper:
            # off-diagonal blocks: each entry once, at (min, max); diagonal
            # blocks hold both (i, k) and (k, i): keep the upper one
            keep = (rows >= 0) & (cols >= 0) & (off | (rows <= cols))
            rows, cols = np.minimum(rows, cols), np.maximum(rows, cols)
        else:
            # off-diagonal blocks also fill their transpose
            keep = (rows >= 0) & (cols >= 0)
            mirror = keep & off
            rows, cols = (
                np.concatenate([rows, cols[mirror]]),
                np.concatenate([cols, rows[mirror]]),
            )
            src = np.concatenate([src, src[mirror]])
            keep = np.concatenate([keep, np.ones(int(mirror.sum()), dtype=bool)])
        rows, cols, src = rows[keep], cols[keep], src[keep]
        key = rows * self.n_free + cols
        uniq, pos = np.unique(key, return_inverse=True)
        r, c = np.divmod(uniq, self.n_free)
        indptr = np.zeros(self.n_free + 1, dtype=np.int64)
        np.cumsum(np.bincount(r, minlength=self.n_free), out=indptr[1:])
        scatter = sp.csr_matrix(
            (np.ones(len(src)), (pos, src)), shape=(len(uniq), self.n_elements * 90)
        )
        pat = Pattern(indptr.astype(np.int32), c.astype(np.int32), scatter, upper)
        self._patterns[upper] = pat
        return pat

    def tangent_data(
        self, kin: Kinematics, modulus: FloatArray, pattern: Pattern
    ) -> FloatArray:
        """CSR data of the free-free tangent in ``pattern``."""
        blocks = self.element_tangent_blocks(kin, modulus, out=self._blocks)
        return pattern.scatter @ blocks.ravel()
