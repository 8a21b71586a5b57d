r"""Vectorised internal force and tangent of any hyperelastic law on P1 tets.

The general-law counterpart of :mod:`idbench_fem.fem.svk_assembly` (which is the
St Venant-Kirchhoff fast path). With one quadrature point per element, the
shape-function gradients G (T, 4, 3) and volumes V are constant; for all
elements at once

.. math::

    F = I + \sum_a u_a \otimes G_a,\qquad
    S = E_e\, S_1(F),\qquad
    f_{ai} = V (F S)_{iJ} G_{aJ},

    K_e = V E_e \left(B^T D_1 B\right) + V\,(G S G^T) \otimes I_3,

with :math:`S_1` and :math:`D_1` the law's second Piola-Kirchhoff stress and
Mandel tangent at unit Young's modulus (every law here is linear in E), B the
Mandel strain variation (:func:`idbench_fem.fem.materials.strain_variation`)
and :math:`E_e` the element's modulus. The element matrices are one batched
matmul; no Python loop runs over elements. The free-free CSR pattern and the
scatter from element matrices to its data are built once.

:class:`LawAssembler` has the public interface the ``solid`` model uses of
:class:`idbench_fem.fem.svk_assembly.Assembler` (``kinematics``, ``forces``,
``region_forces``, ``pattern``, ``tangent_data``, the dof maps), so either
serves the same Newton.

Where numba works (:func:`idbench_fem.fem.kernels.available`), kinematics,
internal force and tangent come from the compiled one-pass loops of
:mod:`idbench_fem.fem.law_kernels` (about an order of magnitude faster, equal
to round-off); the numpy code here is the reference and the fallback.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from idbench_fem.fem import kernels, law_kernels
from idbench_fem.fem.materials import Material, lame, strain_variation
from idbench_fem.fem.svk_assembly import Kinematics, Pattern, TetAssembly

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_I = np.arange(3)


class LawAssembler(TetAssembly):
    """Internal force and tangent of ``law`` on P1 tets with some nodes fixed.

    Parameters
    ----------
    points, tets, free
        As for :class:`~.svk_assembly.TetAssembly`.
    law
        A :class:`idbench_fem.fem.materials.Material` with
        ``linear_in_modulus``; it is evaluated at unit modulus.
    compiled
        Use the compiled kernels (:mod:`~.law_kernels`); None: where numba
        works and ``IDBENCH_NUMBA`` is not 0, for the laws they know.
    """

    STACKS = False
    """One state at a time (:class:`~.svk_assembly.Assembler` takes stacks)."""

    def __init__(
        self,
        points: FloatArray,
        tets: IntArray,
        free: NDArray[np.bool_],
        law: Material,
        compiled: bool | None = None,
    ) -> None:
        if not law.linear_in_modulus:
            raise ValueError(f"law {law.name!r}: need a law linear in the modulus")
        super().__init__(points, tets, free, lame(1.0, law.nu))
        self.law = law.with_modulus(1.0)  # type: ignore[attr-defined]
        self._code = law_kernels.LAW_CODES.get(law.name, -1)
        if compiled is None:
            compiled = kernels.available()
        self.compiled = bool(compiled) and self._code >= 0
        """Whether the compiled kernels are used (else numpy)."""
        self._grads_t = np.ascontiguousarray(self.grads.transpose(0, 2, 1))
        self._emaps: dict[bool, IntArray] = {}

    def kinematics(self, state: FloatArray, modulus: FloatArray) -> Kinematics:
        """F, S = modulus S_1(F) and det F of every element at free displacements.

        Parameters
        ----------
        state
            Free displacements (n,).
        modulus
            Young's modulus per element (T,).
        """
        if self.compiled:
            F, S, det, f = law_kernels.law_kinematics(self._code, state, modulus, self)
            return Kinematics(F, S, det, f)
        u = self._u_full
        u[self.free_dofs] = state
        ue = u.reshape(-1, 3)[self.tets]  # (T, 4, 3)
        F = np.matmul(ue.transpose(0, 2, 1), self.grads)
        F[:, _I, _I] += 1.0
        det = np.linalg.det(F)
        with np.errstate(invalid="ignore", divide="ignore"):
            S = self.law.stress(F)
        S *= modulus[:, None, None]
        return Kinematics(F, S, det)

    def element_tangents(self, kin: Kinematics, modulus: FloatArray) -> FloatArray:
        """Element tangents (T, 12, 12), dofs ordered (node, component)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            D = self.law.mandel_tangent(kin.F)
        D *= (self.volumes * modulus)[:, None, None]
        B = strain_variation(kin.F, self.grads)  # (T, 6, 12)
        K = np.matmul(B.transpose(0, 2, 1), np.matmul(D, B))
        GSG = np.matmul(
            np.matmul(self.grads, kin.S * self.volumes[:, None, None]), self._grads_t
        )
        K5 = K.reshape(-1, 4, 3, 4, 3)
        for i in range(3):
            K5[:, :, i, :, i] += GSG
        return K

    def pattern(self, upper: bool) -> Pattern:
        """Build (once) the CSR pattern and scatter of the free-free tangent."""
        if upper in self._patterns:
            return self._patterns[upper]
        ed = self.element_dofs
        n_el = self.n_elements
        rows = np.broadcast_to(ed[:, :, None], (n_el, 12, 12)).ravel()
        cols = np.broadcast_to(ed[:, None, :], (n_el, 12, 12)).ravel()
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
        self._emaps[upper] = law_kernels.scatter_map(src, pos, n_el)
        return pat

    def tangent_data(
        self, kin: Kinematics, modulus: FloatArray, pattern: Pattern
    ) -> FloatArray:
        """CSR data of the free-free tangent in ``pattern`` (from :meth:`pattern`)."""
        if self.compiled:
            return law_kernels.law_tangent(
                self._code, kin, modulus, self, self._emaps[pattern.upper], pattern.nnz
            )
        return pattern.scatter @ self.element_tangents(kin, modulus).ravel()
