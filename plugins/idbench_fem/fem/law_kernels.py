r"""Compiled kernels of the general-law assembly (numba, optional).

The compiled counterpart of :class:`idbench_fem.fem.law_assembly.LawAssembler`'s
numpy path, for every law of :mod:`idbench_fem.fem.materials`:

- :func:`law_kinematics`: one pass over the tets gives F = I + H, det F, the
  second Piola-Kirchhoff stress S = E_e S_1(F) and the assembled internal
  force f_a = V F S G_a on the free dofs;
- :func:`law_tangent`: one pass gives each element's 12 x 12 tangent and
  scatter-adds it into the CSR data of the fixed pattern through a map built
  once (:func:`scatter_map`), so no sparse matrix is built per iteration.

Per element (one quadrature point, G_a the shape-function gradients, V the
volume, m the element's modulus, lambda and mu at unit modulus) the tangent
of both laws has the form

.. math::

    K_{ai,bk} = V m \left[\lambda\, w_{a,i} w_{b,k} + \beta\, w_{b,i} w_{a,k}
        + \beta\, X_{ik}\, h_{ab} \right] + V \delta_{ik}\, G_a \cdot S G_b

- St Venant-Kirchhoff: w_a = F G_a, beta = mu, X = F F^T, h_ab = G_a . G_b;
- neo-Hookean: w_a = F^{-T} G_a, beta = mu - lambda ln J, X = I,
  h_ab = G_a . C^{-1} G_b,

which is B^T D B + (G S G^T) x I of the Mandel form with the law's tangent
(contracting C^{-1} with F: F C^{-1} = F^{-T}, F C^{-1} F^T = I). F^{-1} is
the closed-form adjugate over det F, C^{-1} = F^{-1} F^{-T}; no
``numpy.linalg`` call. Where det F <= 0 the neo-Hookean results are NaN, as
the numpy path's (a Newton step treats them as failed).

The numpy path stays the reference and the fallback (equal to round-off,
tests/test_fem_law_kernels.py): it is used without numba, when it does not
import, or with ``IDBENCH_NUMBA=0`` (:func:`idbench_fem.fem.kernels.available`).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

LAW_CODES = {"svk": 0, "neo-hookean": 1}
"""The laws the kernels know, by name, and their code in the loops."""


def law_kinematics(
    code: int,
    state: FloatArray,
    modulus: FloatArray,
    dofs: IntArray,
    grads: FloatArray,
    volumes: FloatArray,
    lam: float,
    mu: float,
    n_free: int,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """F, S (T, 3, 3), det F (T,) and the internal force (n,) at one state.

    Parameters
    ----------
    code
        The law's code (:data:`LAW_CODES`).
    state
        Free displacements (n,).
    modulus
        Young's modulus per element (T,).
    dofs
        Free dof of each element's 12 nodal components, -1 if fixed (T, 12).
    grads, volumes
        Shape-function gradients (T, 4, 3) and volumes (T,).
    lam, mu
        Lamé parameters at unit modulus.
    n_free
        Number of free dofs n.
    """
    u = np.ascontiguousarray(state, dtype=np.float64)
    if u.shape != (n_free,):
        raise ValueError(f"state has shape {np.shape(state)}, expected ({n_free},)")
    T = len(dofs)
    mod = np.ascontiguousarray(modulus, dtype=np.float64)
    F = np.empty((T, 3, 3))
    S = np.empty((T, 3, 3))
    det = np.empty(T)
    force = np.zeros(n_free)
    _compiled("kinematics")(code, u, mod, dofs, grads, volumes, lam, mu, F, S, det,
                            force)  # fmt: skip
    return F, S, det, force


def law_tangent(
    code: int,
    F: FloatArray,
    S: FloatArray,
    det: FloatArray,
    modulus: FloatArray,
    grads: FloatArray,
    volumes: FloatArray,
    lam: float,
    mu: float,
    emap: IntArray,
    nnz: int,
) -> FloatArray:
    """CSR data (nnz,) of the tangent at F, S (from :func:`law_kinematics`).

    ``emap`` (T, 144) is the position in the data of each element matrix
    entry (row-major, dofs ordered (node, component)), -1 where it is not
    stored (a fixed dof, or the lower triangle of an upper pattern).
    """
    data = np.zeros(nnz)
    mod = np.ascontiguousarray(modulus, dtype=np.float64)
    _compiled("tangent")(code, F, S, det, mod, grads, volumes, lam, mu, emap, data)
    return data


def scatter_map(src: IntArray, pos: IntArray, n_elements: int) -> IntArray:
    """The (T, 144) map of :func:`law_tangent` from a pattern's COO -> CSR pairs.

    ``src`` are the kept entries' flat indices into the (T, 12, 12) element
    matrices, ``pos`` their positions in the CSR data.
    """
    emap = np.full(n_elements * 144, -1, dtype=np.int64)
    emap[src] = pos
    return emap.reshape(n_elements, 144)


@functools.cache
def _compiled(which: str) -> Callable[..., Any]:
    """The numba loop ``which``, compiled (or loaded from numba's cache)."""
    import numba

    fn = {"kinematics": _kinematics_loop, "tangent": _tangent_loop}[which]
    try:
        return numba.njit(cache=True, nogil=True)(fn)  # type: ignore[no-any-return]
    except RuntimeError as exc:  # nowhere writable to cache: compile each process
        log.warning("numba cannot cache the kernel (%s); compiling it here", exc)
        return numba.njit(nogil=True)(fn)  # type: ignore[no-any-return]


def _kinematics_loop(  # type: ignore[no-untyped-def]
    code, u, modulus, dofs, grads, volumes, lam, mu, F, S, det, force
):
    """Loops of :func:`law_kinematics`, writing F, S, det and force in place."""
    T = len(modulus)
    ue = np.empty(12)
    for e in range(T):
        for c in range(12):
            d = dofs[e, c]
            ue[c] = u[d] if d >= 0 else 0.0
        f00 = f11 = f22 = 1.0
        f01 = f02 = f10 = f12 = f20 = f21 = 0.0
        for a in range(4):
            g0, g1, g2 = grads[e, a, 0], grads[e, a, 1], grads[e, a, 2]
            x, y, z = ue[3 * a], ue[3 * a + 1], ue[3 * a + 2]
            f00 += x * g0
            f01 += x * g1
            f02 += x * g2
            f10 += y * g0
            f11 += y * g1
            f12 += y * g2
            f20 += z * g0
            f21 += z * g1
            f22 += z * g2
        # cofactors of F: F^-1 = adj(F) / J
        a00 = f11 * f22 - f12 * f21
        a01 = f02 * f21 - f01 * f22
        a02 = f01 * f12 - f02 * f11
        a10 = f12 * f20 - f10 * f22
        a11 = f00 * f22 - f02 * f20
        a12 = f02 * f10 - f00 * f12
        a20 = f10 * f21 - f11 * f20
        a21 = f01 * f20 - f00 * f21
        a22 = f00 * f11 - f01 * f10
        J = f00 * a00 + f01 * a10 + f02 * a20
        det[e] = J
        m = modulus[e]
        if code == 0:  # St Venant-Kirchhoff: S = lambda tr(E) I + 2 mu E
            e00 = 0.5 * (f00 * f00 + f10 * f10 + f20 * f20 - 1.0)
            e11 = 0.5 * (f01 * f01 + f11 * f11 + f21 * f21 - 1.0)
            e22 = 0.5 * (f02 * f02 + f12 * f12 + f22 * f22 - 1.0)
            e01 = 0.5 * (f00 * f01 + f10 * f11 + f20 * f21)
            e02 = 0.5 * (f00 * f02 + f10 * f12 + f20 * f22)
            e12 = 0.5 * (f01 * f02 + f11 * f12 + f21 * f22)
            tr = lam * (e00 + e11 + e22)
            s00 = m * (2.0 * mu * e00 + tr)
            s11 = m * (2.0 * mu * e11 + tr)
            s22 = m * (2.0 * mu * e22 + tr)
            s01 = m * (2.0 * mu * e01)
            s02 = m * (2.0 * mu * e02)
            s12 = m * (2.0 * mu * e12)
        else:  # neo-Hookean: S = mu (I - C^-1) + lambda ln J C^-1
            lnJ = np.log(J) if J > 0.0 else np.nan
            r = 1.0 / J
            i00, i01, i02 = a00 * r, a01 * r, a02 * r  # F^-1
            i10, i11, i12 = a10 * r, a11 * r, a12 * r
            i20, i21, i22 = a20 * r, a21 * r, a22 * r
            c = lam * lnJ - mu  # S = mu I + c C^-1, C^-1 = F^-1 F^-T
            s00 = m * (mu + c * (i00 * i00 + i01 * i01 + i02 * i02))
            s11 = m * (mu + c * (i10 * i10 + i11 * i11 + i12 * i12))
            s22 = m * (mu + c * (i20 * i20 + i21 * i21 + i22 * i22))
            s01 = m * (c * (i00 * i10 + i01 * i11 + i02 * i12))
            s02 = m * (c * (i00 * i20 + i01 * i21 + i02 * i22))
            s12 = m * (c * (i10 * i20 + i11 * i21 + i12 * i22))
        Fe, Se = F[e], S[e]
        Fe[0, 0], Fe[0, 1], Fe[0, 2] = f00, f01, f02
        Fe[1, 0], Fe[1, 1], Fe[1, 2] = f10, f11, f12
        Fe[2, 0], Fe[2, 1], Fe[2, 2] = f20, f21, f22
        Se[0, 0], Se[0, 1], Se[0, 2] = s00, s01, s02
        Se[1, 0], Se[1, 1], Se[1, 2] = s01, s11, s12
        Se[2, 0], Se[2, 1], Se[2, 2] = s02, s12, s22
        # P = V F S, f_ai = P_iJ G_aJ
        v = volumes[e]
        p00 = v * (f00 * s00 + f01 * s01 + f02 * s02)
        p01 = v * (f00 * s01 + f01 * s11 + f02 * s12)
        p02 = v * (f00 * s02 + f01 * s12 + f02 * s22)
        p10 = v * (f10 * s00 + f11 * s01 + f12 * s02)
        p11 = v * (f10 * s01 + f11 * s11 + f12 * s12)
        p12 = v * (f10 * s02 + f11 * s12 + f12 * s22)
        p20 = v * (f20 * s00 + f21 * s01 + f22 * s02)
        p21 = v * (f20 * s01 + f21 * s11 + f22 * s12)
        p22 = v * (f20 * s02 + f21 * s12 + f22 * s22)
        for a in range(4):
            g0, g1, g2 = grads[e, a, 0], grads[e, a, 1], grads[e, a, 2]
            d = dofs[e, 3 * a]
            if d >= 0:
                force[d] += p00 * g0 + p01 * g1 + p02 * g2
            d = dofs[e, 3 * a + 1]
            if d >= 0:
                force[d] += p10 * g0 + p11 * g1 + p12 * g2
            d = dofs[e, 3 * a + 2]
            if d >= 0:
                force[d] += p20 * g0 + p21 * g1 + p22 * g2


def _tangent_loop(  # type: ignore[no-untyped-def]
    code, F, S, det, modulus, grads, volumes, lam, mu, emap, data
):
    """Loops of :func:`law_tangent`, scatter-adding into ``data`` (zeros)."""
    T = len(modulus)
    w = np.empty((4, 3))  # w_a
    X = np.empty((3, 3))
    M = np.empty((3, 3))  # the metric of h_ab: I (SVK) or C^-1
    for e in range(T):
        Fe = F[e]
        Se = S[e]
        vol = volumes[e]
        v = vol * modulus[e]
        if code == 0:
            beta = mu
            for i in range(3):
                for k in range(3):
                    X[i, k] = (
                        Fe[i, 0] * Fe[k, 0] + Fe[i, 1] * Fe[k, 1] + Fe[i, 2] * Fe[k, 2]
                    )
                    M[i, k] = 1.0 if i == k else 0.0
            for a in range(4):
                for i in range(3):
                    w[a, i] = (
                        Fe[i, 0] * grads[e, a, 0]
                        + Fe[i, 1] * grads[e, a, 1]
                        + Fe[i, 2] * grads[e, a, 2]
                    )
        else:
            J = det[e]
            lnJ = np.log(J) if J > 0.0 else np.nan
            beta = mu - lam * lnJ
            r = 1.0 / J
            # F^-1 by cofactors; iF[I, i]
            f00, f01, f02 = Fe[0, 0], Fe[0, 1], Fe[0, 2]
            f10, f11, f12 = Fe[1, 0], Fe[1, 1], Fe[1, 2]
            f20, f21, f22 = Fe[2, 0], Fe[2, 1], Fe[2, 2]
            i00 = (f11 * f22 - f12 * f21) * r
            i01 = (f02 * f21 - f01 * f22) * r
            i02 = (f01 * f12 - f02 * f11) * r
            i10 = (f12 * f20 - f10 * f22) * r
            i11 = (f00 * f22 - f02 * f20) * r
            i12 = (f02 * f10 - f00 * f12) * r
            i20 = (f10 * f21 - f11 * f20) * r
            i21 = (f01 * f20 - f00 * f21) * r
            i22 = (f00 * f11 - f01 * f10) * r
            M[0, 0] = i00 * i00 + i01 * i01 + i02 * i02
            M[1, 1] = i10 * i10 + i11 * i11 + i12 * i12
            M[2, 2] = i20 * i20 + i21 * i21 + i22 * i22
            M[0, 1] = M[1, 0] = i00 * i10 + i01 * i11 + i02 * i12
            M[0, 2] = M[2, 0] = i00 * i20 + i01 * i21 + i02 * i22
            M[1, 2] = M[2, 1] = i10 * i20 + i11 * i21 + i12 * i22
            for i in range(3):
                for k in range(3):
                    X[i, k] = 1.0 if i == k else 0.0
            for a in range(4):
                g0, g1, g2 = grads[e, a, 0], grads[e, a, 1], grads[e, a, 2]
                # w_a = F^-T G_a: w_i = iF[J, i] G_J
                w[a, 0] = i00 * g0 + i10 * g1 + i20 * g2
                w[a, 1] = i01 * g0 + i11 * g1 + i21 * g2
                w[a, 2] = i02 * g0 + i12 * g1 + i22 * g2
        row = emap[e]
        for a in range(4):
            for b in range(4):
                h = 0.0
                geo = 0.0
                for J in range(3):
                    ga = grads[e, a, J]
                    for L in range(3):
                        gb = grads[e, b, L]
                        h += ga * M[J, L] * gb
                        geo += ga * Se[J, L] * gb
                for i in range(3):
                    base = 12 * (3 * a + i) + 3 * b
                    for k in range(3):
                        idx = row[base + k]
                        if idx < 0:
                            continue
                        val = v * (
                            lam * w[a, i] * w[b, k]
                            + beta * (w[b, i] * w[a, k] + X[i, k] * h)
                        )
                        if i == k:
                            val += vol * geo  # S carries the modulus
                        data[idx] += val
