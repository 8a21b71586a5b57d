r"""Springs on surface regions (Robin supports): constant matrices, one wrapper.

A support region :math:`\Gamma_s` held by springs of stiffness per unit area
:math:`k_n` (normal) and :math:`k_t` (tangential) has the traction
:math:`\mathbf{t} = -(k_n \mathbf{n}\mathbf{n}^T + k_t (\mathbf{I} -
\mathbf{n}\mathbf{n}^T)) \mathbf{u}` (reference normal). Its nodal forces are
linear in u and in each stiffness,

.. math::

    f_s(u) = (k_n S_n + k_t S_t)\, u, \qquad
    S_n = \int_{\Gamma_s} N^T \mathbf{n}\mathbf{n}^T N \, dA, \quad
    S_t = \int_{\Gamma_s} N^T (\mathbf{I} - \mathbf{n}\mathbf{n}^T) N \, dA,

with the P1 triangle's consistent integrals :math:`\int N_a N_b\, dA = A (1 +
\delta_{ab}) / 12` (exact; a uniform displacement u gets k A u in all).
:func:`spring_matrices` assembles :math:`S_n, S_t` once per region, sparse
on the free dofs; they are constant, so the tangent gains
:math:`\sum_c k_c S_c` and the internal force :math:`\sum_c k_c S_c u` at
the cost of a sparse product per channel c.

:class:`SpringAssembler` wraps an assembler of the free dofs
(:class:`~idbench_fem.fem.svk_assembly.Assembler` or
:class:`~idbench_fem.fem.law_assembly.LawAssembler`) and keeps its
interface: the channels' stiffnesses ride at the end of the moduli array,
``modulus = [E_1 .. E_T, k_1 .. k_q]`` (one row per state for a stack), so
Newton, the path steps and the batched sigma points
(:mod:`idbench_fem.fem.newton`, :mod:`~idbench_fem.fem.batched`) solve with
springs unchanged. A stiffness that is a parameter theta_j has the
sensitivity of a modulus, du/dtheta_j = -K^-1 S_c u: :meth:`region_forces`
gives :math:`S_c u` as its column.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from idbench_fem.fem.svk_assembly import Kinematics, Pattern

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_PAIR = (np.ones((3, 3)) + np.eye(3)) / 12.0
"""The P1 triangle's integrals of N_a N_b over its area, per unit area."""


def spring_matrices(
    points: FloatArray, triangles: IntArray, full_to_free: IntArray
) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """S_n and S_t (n, n) of springs of unit stiffness on ``triangles``.

    Parameters
    ----------
    points
        Node coordinates (N, 3).
    triangles
        The region's boundary facets (F, 3), outward by the right-hand rule.
    full_to_free
        Free dof index of each full dof (3N,), -1 where fixed.
    """
    tri = np.asarray(triangles, dtype=np.int64)
    p = points[tri]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    n = normal / (2.0 * area)[:, None]
    nn = n[:, :, None] * n[:, None, :]  # (F, 3, 3)
    dofs = full_to_free[(3 * tri[:, :, None] + np.arange(3)).reshape(-1, 9)]
    rows = np.broadcast_to(dofs[:, :, None], (len(tri), 9, 9)).ravel()
    cols = np.broadcast_to(dofs[:, None, :], (len(tri), 9, 9)).ravel()
    keep = (rows >= 0) & (cols >= 0)
    size = int(full_to_free.max()) + 1
    out = []
    for block in (nn, np.eye(3) - nn):
        # (F, a, i, b, k) = A M_ab P_ik
        e = area[:, None, None, None, None] * (
            _PAIR[None, :, None, :, None] * block[:, None, :, None, :]
        )
        m = sp.csr_matrix(
            (e.ravel()[keep], (rows[keep], cols[keep])), shape=(size, size)
        )
        m.sum_duplicates()
        m.sort_indices()
        out.append(m)
    return out[0], out[1]


@dataclass
class SpringKinematics(Kinematics):
    """:class:`Kinematics` with the state u and the springs' stiffnesses k.

    ``u`` (n,) or (r, n); ``k`` (q,) or (r, q), one per channel.
    """

    u: FloatArray | None = None
    k: FloatArray | None = None


class SpringAssembler:
    """An assembler of the free dofs with springs added (see the module).

    Parameters
    ----------
    inner
        The assembler of the elastic body.
    matrices
        One constant sparse (n, n) matrix per channel c (:func:`spring_matrices`).
    parameters
        (parameter index j, channel c) of the stiffnesses that are parameters:
        :meth:`region_forces` fills column j with S_c u.
    """

    _SHARED = ("n_free", "n_elements", "n_nodes", "volumes", "compiled", "STACKS",
               "full_to_free", "free_dofs", "element_dofs", "tets")  # fmt: skip

    def __init__(
        self,
        inner: Any,
        matrices: list[sp.csr_matrix],
        parameters: tuple[tuple[int, int], ...] = (),
    ) -> None:
        self.inner = inner
        for name in self._SHARED:
            setattr(self, name, getattr(inner, name))
        self.matrices = tuple(sp.csr_matrix(m) for m in matrices)
        self.parameters = tuple(parameters)
        self._slots: dict[bool, list[IntArray]] = {}

    def __getattr__(self, name: str) -> Any:
        """Anything else the inner assembler has (element tangents, buffers)."""
        if name == "inner" or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.inner, name)

    @property
    def n_channels(self) -> int:
        """Number of spring matrices q (their stiffnesses end the moduli array)."""
        return len(self.matrices)

    def kinematics(self, state: FloatArray, modulus: FloatArray) -> SpringKinematics:
        """The inner kinematics at the moduli ``modulus[..., :T]``, with u and k.

        ``modulus`` (T + q,) or (r, T + q); with only (T,) (the sensitivity's
        unit moduli) k is zero: :meth:`region_forces` needs only u.
        """
        m = np.asarray(modulus, dtype=np.float64)
        T = self.n_elements
        kin = self.inner.kinematics(state, np.ascontiguousarray(m[..., :T]))
        k = m[..., T:] if m.shape[-1] > T else np.zeros((*m.shape[:-1], 0))
        return SpringKinematics(
            kin.F, kin.S, kin.det, kin.forces, np.asarray(state, dtype=np.float64), k
        )

    def spring_forces(self, u: FloatArray, k: FloatArray) -> FloatArray:
        """Sum_c k_c S_c u, (n,) or (r, n) for a stack (k (q,) or (r, q))."""
        out = np.zeros(u.shape)
        for c, S in enumerate(self.matrices[: k.shape[-1]]):
            if u.ndim == 1:
                out += k[c] * (S @ u)
            else:
                out += k[:, c, None] * np.asarray(S @ u.T).T
        return out

    def forces(self, kin: SpringKinematics) -> FloatArray:
        """Internal force with the springs' (n,) (or (r, n) for a stack)."""
        f = np.asarray(self.inner.forces(kin))
        assert kin.u is not None and kin.k is not None
        if kin.k.shape[-1]:
            f = f + self.spring_forces(kin.u, kin.k)
        return f

    def element_forces(self, kin: Kinematics) -> FloatArray:
        """The elastic element forces (..., T, 4, 3), without the springs."""
        return np.asarray(self.inner.element_forces(kin))

    def region_forces(
        self, kin_unit: SpringKinematics, regions: IntArray, p: int
    ) -> FloatArray:
        """Column j: g_j, a region's elastic force or a stiffness's S_c u, (n, p)."""
        g = np.asarray(self.inner.region_forces(kin_unit, regions, p))
        assert kin_unit.u is not None
        for j, c in self.parameters:
            g[:, j] = self.matrices[c] @ kin_unit.u
        return g

    def pattern(self, upper: bool) -> Pattern:
        """The inner pattern (the springs couple nodes of a facet: in it)."""
        pat = self.inner.pattern(upper)
        if upper not in self._slots:
            self._slots[upper] = [_slots(pat, S) for S in self.matrices]
        return pat

    def tangent_data(
        self, kin: SpringKinematics, modulus: FloatArray, pattern: Pattern
    ) -> FloatArray:
        """CSR data of the tangent in ``pattern``: elastic plus sum_c k_c S_c."""
        m = np.asarray(modulus, dtype=np.float64)
        T = self.n_elements
        data = np.array(self.inner.tangent_data(kin, m[:T], pattern))
        self.pattern(pattern.upper)
        for c, (slots, values) in enumerate(self._slots[pattern.upper]):
            if T + c < len(m):
                data[slots] += m[T + c] * values  # slots are distinct
        return data


def _slots(pattern: Pattern, S: sp.csr_matrix) -> tuple[IntArray, FloatArray]:
    """Where each stored entry of S lies in ``pattern``'s data, and its value.

    Only the upper triangle where the pattern keeps only that. Raises
    ValueError if an entry is outside the pattern (a spring coupling nodes
    that no tet couples).
    """
    coo = S.tocoo()
    r, c, v = coo.row.astype(np.int64), coo.col.astype(np.int64), coo.data
    if pattern.upper:
        keep = r <= c
        r, c, v = r[keep], c[keep], v[keep]
    n = len(pattern.indptr) - 1
    row_of = np.repeat(np.arange(n, dtype=np.int64), np.diff(pattern.indptr))
    keys = row_of * n + pattern.indices.astype(np.int64)
    want = r * n + c
    pos = np.searchsorted(keys, want)
    pos = np.minimum(pos, len(keys) - 1)
    if len(want) and not np.array_equal(keys[pos], want):
        raise ValueError("a spring couples dofs outside the tangent's pattern")
    return pos.astype(np.int64), np.asarray(v, dtype=np.float64)
