r"""Element kernels of both laws on any set of P1 tets, from element displacements.

The assemblers (:mod:`~.svk_assembly`, :mod:`~.law_assembly`) work on a mesh's
free dofs and assemble sparse tangents; a reduced model needs the same
element quantities on a few *sampled* elements, from displacements it lifts
element by element (:mod:`~.hyper`), and the offline sampling needs every
element's force at a snapshot (:mod:`~.ecsw`). :class:`ElementSet` gives both:
for element displacements u (T, 4, 3) (node a, component i)

.. math::

    F = I + \sum_a u_a \otimes G_a,\qquad
    f_{ai} = V (F S)_{iJ} G_{aJ},

    K_{ai,bk} = V m \left[\lambda\, w_{a,i} w_{b,k} + \beta\, w_{b,i} w_{a,k}
        + \beta\, X_{ik}\, h_{ab} \right] + V \delta_{ik}\, G_a \cdot S G_b,

with m the element's modulus, S = m S_1(F), lambda and mu at unit modulus,
and (as in :mod:`~.law_kernels`)

- St Venant-Kirchhoff: S_1 = lambda tr(E) I + 2 mu E, w_a = F G_a,
  beta = mu, X = F F^T, h_ab = G_a . G_b;
- neo-Hookean: S_1 = mu (I - C^-1) + lambda ln J C^-1, w_a = F^-T G_a,
  beta = mu - lambda ln J, X = I, h_ab = G_a . C^-1 G_b.

Both are linear in m: f and K at modulus m are m times their unit values
(the geometric term through S). Everything is vectorised over the elements
(numpy); where det F <= 0 the neo-Hookean results are NaN, as the
assemblers' (a Newton step treats them as failed). Tested against
:class:`~.law_assembly.LawAssembler` (tests/fem/test_reduced_model.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from idbench_fem.fem.materials import lame

FloatArray = NDArray[np.float64]

LAWS = ("svk", "neo-hookean")
"""The laws the kernels know."""

_I3 = np.eye(3)


@dataclass(frozen=True)
class ElementState:
    """Per-element kinematics at one displacement, at unit modulus.

    Attributes
    ----------
    F
        Deformation gradients (T, 3, 3).
    det
        det F (T,).
    S1
        Second Piola-Kirchhoff stress at unit modulus (T, 3, 3).
    Finv
        F^-1 (T, 3, 3) (neo-Hookean only, else None).
    log_det
        ln det F (T,) (neo-Hookean only, else None).
    """

    F: FloatArray
    det: FloatArray
    S1: FloatArray
    Finv: FloatArray | None = None
    log_det: FloatArray | None = None

    def take(self, members: NDArray[np.int64]) -> ElementState:
        """The state of the elements ``members`` only."""
        return ElementState(*(None if a is None else a[members] for a in (
            self.F, self.det, self.S1, self.Finv, self.log_det)))  # fmt: skip


class ElementSet:
    """P1 tets (their gradients and volumes) and a law, for element-wise kernels.

    Parameters
    ----------
    grads
        Shape-function gradients (T, 4, 3).
    volumes
        Element volumes (T,).
    law
        ``"svk"`` or ``"neo-hookean"``.
    nu
        Poisson's ratio (the law is evaluated at unit modulus).
    """

    def __init__(
        self, grads: FloatArray, volumes: FloatArray, law: str, nu: float
    ) -> None:
        if law not in LAWS:
            raise ValueError(f"law {law!r}: allowed are {', '.join(LAWS)}")
        self.grads = np.ascontiguousarray(grads, dtype=np.float64)
        self.volumes = np.ascontiguousarray(volumes, dtype=np.float64)
        self.law, self.nu = law, float(nu)
        self.lam, self.mu = lame(1.0, nu)
        self._gg = np.matmul(self.grads, self.grads.transpose(0, 2, 1))  # (T, 4, 4)

    def __len__(self) -> int:
        return len(self.volumes)

    def subset(self, members: NDArray[np.int64]) -> ElementSet:
        """The same law on the elements ``members`` only."""
        return ElementSet(self.grads[members], self.volumes[members], self.law, self.nu)

    def state(self, ue: FloatArray) -> ElementState:
        """Kinematics and unit stress at element displacements ``ue`` (T, 4, 3)."""
        F = np.matmul(ue.transpose(0, 2, 1), self.grads)  # F_iJ = u_ai G_aJ
        F[:, 0, 0] += 1.0
        F[:, 1, 1] += 1.0
        F[:, 2, 2] += 1.0
        det = _det(F)
        if self.law == "svk":
            E = 0.5 * (np.matmul(F.transpose(0, 2, 1), F) - _I3)
            S1 = (2.0 * self.mu) * E
            tr = E[:, 0, 0] + E[:, 1, 1] + E[:, 2, 2]
            S1[:, 0, 0] += self.lam * tr
            S1[:, 1, 1] += self.lam * tr
            S1[:, 2, 2] += self.lam * tr
            return ElementState(F, det, S1)
        with np.errstate(invalid="ignore", divide="ignore"):
            Finv = _adjugate(F) / det[:, None, None]
            log_det = np.where(det > 0, np.log(np.where(det > 0, det, 1.0)), np.nan)
        Cinv = np.matmul(Finv, Finv.transpose(0, 2, 1))
        S1 = (self.lam * log_det - self.mu)[:, None, None] * Cinv
        S1[:, 0, 0] += self.mu
        S1[:, 1, 1] += self.mu
        S1[:, 2, 2] += self.mu
        return ElementState(F, det, S1, Finv, log_det)

    def forces(self, st: ElementState, modulus: FloatArray) -> FloatArray:
        """Element internal forces (T, 12) at ``modulus`` (T,): m V (F S_1) G_a."""
        P = np.matmul(st.F, st.S1) * (self.volumes * modulus)[:, None, None]
        return np.matmul(self.grads, P.transpose(0, 2, 1)).reshape(-1, 12)

    def tangents(self, st: ElementState, modulus: FloatArray) -> FloatArray:
        """Element tangents (T, 12, 12) at ``modulus`` (T,), dofs (node, component)."""
        G = self.grads
        if self.law == "svk":
            w = np.matmul(G, st.F.transpose(0, 2, 1))  # w_ai = F_iJ G_aJ
            beta = np.full(len(G), self.mu)
            X = np.matmul(st.F, st.F.transpose(0, 2, 1))
            h = self._gg
        else:
            assert st.Finv is not None and st.log_det is not None
            w = np.matmul(G, st.Finv)  # w_ai = Finv_Ji G_aJ
            beta = self.mu - self.lam * st.log_det
            Cinv = np.matmul(st.Finv, st.Finv.transpose(0, 2, 1))
            X = np.broadcast_to(_I3, st.F.shape)
            h = np.matmul(np.matmul(G, Cinv), G.transpose(0, 2, 1))
        vm = self.volumes * modulus
        T = len(G)
        # K[t, a, i, b, k], each term by broadcasting (faster than einsum here)
        K = (self.lam * vm)[:, None, None, None, None] * (
            w[:, :, :, None, None] * w[:, None, None, :, :]
        )
        bv = (beta * vm)[:, None, None, None, None]
        K += bv * (w.transpose(0, 2, 1)[:, None, :, :, None] * w[:, :, None, None, :])
        K += bv * (X[:, None, :, None, :] * h[:, :, None, :, None])
        gsg = np.matmul(np.matmul(G, st.S1), G.transpose(0, 2, 1)) * vm[:, None, None]
        for i in range(3):
            K[:, :, i, :, i] += gsg
        assert K.shape == (T, 4, 3, 4, 3)
        return K.reshape(-1, 12, 12)


def _det(F: FloatArray) -> FloatArray:
    return np.asarray(
        F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
        - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
        + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0])
    )


def _adjugate(F: FloatArray) -> FloatArray:
    """The adjugate of each 3 x 3 matrix (T, 3, 3): F^-1 = adj F / det F."""
    a = np.empty_like(F)
    a[:, 0, 0] = F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1]
    a[:, 0, 1] = F[:, 0, 2] * F[:, 2, 1] - F[:, 0, 1] * F[:, 2, 2]
    a[:, 0, 2] = F[:, 0, 1] * F[:, 1, 2] - F[:, 0, 2] * F[:, 1, 1]
    a[:, 1, 0] = F[:, 1, 2] * F[:, 2, 0] - F[:, 1, 0] * F[:, 2, 2]
    a[:, 1, 1] = F[:, 0, 0] * F[:, 2, 2] - F[:, 0, 2] * F[:, 2, 0]
    a[:, 1, 2] = F[:, 0, 2] * F[:, 1, 0] - F[:, 0, 0] * F[:, 1, 2]
    a[:, 2, 0] = F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]
    a[:, 2, 1] = F[:, 0, 1] * F[:, 2, 0] - F[:, 0, 0] * F[:, 2, 1]
    a[:, 2, 2] = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
    return a
