r"""Prescribed displacements: an assembler on the unknown dofs of a driven body.

A displacement-controlled manipulation (a grasp that moves its patch by a
given displacement) prescribes every component of some nodes. The model's
state keeps all the dofs that are not fixed (the prescribed ones hold their
value at the step), but Newton solves only for the others, the *unknowns*:
with u = (u_f, u_p), u_p given,

.. math::

    r(u_f) = f_{int,f}(u_f, u_p) = 0, \qquad
    K_{ff}\, \delta u_f = -r,

and the tool's force is :math:`f_{int,p}(u_f, u_p)` (the internal force at
the prescribed dofs, which the tool balances).

:class:`PrescribedAssembler` wraps an assembler whose free dofs are the
state's (:class:`~idbench_fem.fem.svk_assembly.Assembler` or
:class:`~idbench_fem.fem.law_assembly.LawAssembler`) and gives the same
interface on the unknowns, with the prescribed values of the step
(:attr:`PrescribedAssembler.values`, set by the model before it solves a
step) in every kinematics: Newton, the batched steps and the path reuse
(:mod:`idbench_fem.fem.newton`, :mod:`idbench_fem.fem.batched`) then solve the
reduced problem unchanged. The tangent is the inner one restricted to the
unknowns (its CSR data gathered, no second assembly).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from idbench_fem.fem.svk_assembly import Pattern

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class PrescribedAssembler:
    """An assembler on the unknown dofs, the prescribed ones set to :attr:`values`.

    Parameters
    ----------
    inner
        The assembler of the whole state (fixed nodes removed, prescribed
        nodes kept).
    prescribed
        Indices (into the inner free dofs) of the prescribed dofs.
    """

    def __init__(self, inner: Any, prescribed: IntArray) -> None:
        self.inner = inner
        n = int(inner.n_free)
        mask = np.zeros(n, dtype=bool)
        mask[np.asarray(prescribed, dtype=np.int64)] = True
        self.prescribed = np.flatnonzero(mask)
        self.unknown = np.flatnonzero(~mask)
        self.n_free = len(self.unknown)
        self.n_elements = inner.n_elements
        self.volumes = inner.volumes
        self.compiled = inner.compiled
        self.STACKS = inner.STACKS
        self.values = np.zeros(len(self.prescribed))
        """The prescribed dofs' values (m), those of the step being solved."""
        self._patterns: dict[bool, tuple[Pattern, IntArray]] = {}

    def embed(self, state: FloatArray, values: FloatArray | None = None) -> FloatArray:
        """The inner state (..., n_inner) of unknowns ``state`` (..., n)."""
        state = np.asarray(state, dtype=np.float64)
        out = np.empty((*state.shape[:-1], int(self.inner.n_free)))
        out[..., self.unknown] = state
        out[..., self.prescribed] = self.values if values is None else values
        return out

    def kinematics(self, state: FloatArray, modulus: FloatArray) -> Any:
        """The inner kinematics at the unknowns ``state`` and :attr:`values`."""
        return self.inner.kinematics(self.embed(state), modulus)

    def forces(self, kin: Any) -> FloatArray:
        """Internal force on the unknowns, (n,) (or (r, n) for a stack)."""
        return np.asarray(self.inner.forces(kin)[..., self.unknown])

    def element_forces(self, kin: Any) -> FloatArray:
        """The inner element forces (..., T, 4, 3)."""
        return np.asarray(self.inner.element_forces(kin))

    def region_forces(self, kin_unit: Any, regions: IntArray, p: int) -> FloatArray:
        """Each region's internal force g_r on the unknowns, (n, p)."""
        return np.asarray(self.inner.region_forces(kin_unit, regions, p)[self.unknown])

    def pattern(self, upper: bool) -> Pattern:
        """The inner pattern restricted to the unknowns (built once)."""
        if upper not in self._patterns:
            full = self.inner.pattern(upper)
            n = len(full.indptr) - 1
            slots = sp.csr_matrix(
                (np.arange(1, full.nnz + 1, dtype=np.float64), full.indices,
                 full.indptr),
                shape=(n, n),
            )  # fmt: skip
            sub = slots[self.unknown][:, self.unknown].tocsr()
            sub.sort_indices()
            take = sub.data.astype(np.int64) - 1
            pat = Pattern(
                sub.indptr.astype(np.int32),
                sub.indices.astype(np.int32),
                full.scatter[take],
                upper,
            )
            self._patterns[upper] = (pat, take)
        return self._patterns[upper][0]

    def tangent_data(
        self, kin: Any, modulus: FloatArray, pattern: Pattern
    ) -> FloatArray:
        """CSR data of the unknowns' tangent K_ff in ``pattern`` (:meth:`pattern`)."""
        self.pattern(pattern.upper)
        take = self._patterns[pattern.upper][1]
        full = self.inner.pattern(pattern.upper)
        return np.asarray(self.inner.tangent_data(kin, modulus, full)[take])
