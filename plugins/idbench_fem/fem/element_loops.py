r"""The compiled element loops (numba), and the per-element steps they share.

Imported only where numba works (:func:`idbench_fem.fem.kernels.loops`), so
numba stays optional. Three loops over P1 tets, each calling the same small
compiled steps, which numba inlines into them (``inline="always"``: as fast
as the steps written out in each loop; no fast-math, so every step does the
same floating-point operations in the same order as written out, and the
results are unchanged to the bit):

- :func:`svk_kinematics` (:func:`idbench_fem.fem.kernels.svk_kinematics`):
  F, S, det F and the force of a stack of states, St Venant-Kirchhoff with the
  strain from the displacement gradient H, E = (H + H^T + H^T H) / 2;
- :func:`law_kinematics` and :func:`law_tangent`
  (:mod:`idbench_fem.fem.law_kernels`): the general laws, from F.

The shared steps: :func:`gather` (an element's 12 nodal values),
:func:`gradient` (H or F = I + H), :func:`svk_stress`, :func:`store` (F and S
into their arrays), :func:`add_force` (P = V F S, then f_a = P G_a scattered
on the free dofs), :func:`inverse` and :func:`gram` (F^-1, C^-1 = F^-1 F^-T).
F and S travel as tuples, F row-major (9), S symmetric as (00, 11, 22, 01, 02,
12).

All functions live in this one module on purpose: numba's disk cache of a
loop does not notice a change in a step defined in another file.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

log = logging.getLogger(__name__)


def _jit(fn: Callable[..., Any], inline: str = "never") -> Callable[..., Any]:
    """``fn`` compiled with numba, cached on disk where a folder is writable."""
    try:
        return numba.njit(cache=True, nogil=True, inline=inline)(fn)  # type: ignore[no-any-return]
    except RuntimeError as exc:  # nowhere writable to cache: compile each process
        log.warning("numba cannot cache %s (%s); compiling it here", fn.__name__, exc)
        return numba.njit(nogil=True, inline=inline)(fn)  # type: ignore[no-any-return]


def _step(fn: Callable[..., Any]) -> Callable[..., Any]:
    """A per-element step: compiled, and inlined into the loops that call it."""
    return _jit(fn, inline="always")


# --- the steps of one element ----------------------------------------------------


@_step
def gather(u, dofs, e, ue):  # type: ignore[no-untyped-def]
    """Element ``e``'s 12 nodal values of the free ``u`` into ``ue`` (0 if fixed)."""
    for c in range(12):
        d = dofs[e, c]
        ue[c] = u[d] if d >= 0 else 0.0


@_step
def gradient(ue, grads, e, diag):  # type: ignore[no-untyped-def]
    """``diag`` I + sum_a u_a G_a^T, row-major: H (``diag`` 0) or F (``diag`` 1)."""
    g00 = g11 = g22 = diag
    g01 = g02 = g10 = g12 = g20 = g21 = 0.0
    for a in range(4):
        g0, g1, g2 = grads[e, a, 0], grads[e, a, 1], grads[e, a, 2]
        x, y, z = ue[3 * a], ue[3 * a + 1], ue[3 * a + 2]
        g00 += x * g0
        g01 += x * g1
        g02 += x * g2
        g10 += y * g0
        g11 += y * g1
        g12 += y * g2
        g20 += z * g0
        g21 += z * g1
        g22 += z * g2
    return g00, g01, g02, g10, g11, g12, g20, g21, g22


@_step
def svk_stress(strain, m, lam, mu):  # type: ignore[no-untyped-def]
    """S = m (lambda tr(E) I + 2 mu E) of a symmetric E (00, 11, 22, 01, 02, 12)."""
    e00, e11, e22, e01, e02, e12 = strain
    tr = lam * (e00 + e11 + e22)
    return (
        m * (2.0 * mu * e00 + tr),
        m * (2.0 * mu * e11 + tr),
        m * (2.0 * mu * e22 + tr),
        m * (2.0 * mu * e01),
        m * (2.0 * mu * e02),
        m * (2.0 * mu * e12),
    )


@_step
def store(Fe, Se, f, s):  # type: ignore[no-untyped-def]
    """Write F (row-major tuple) and the symmetric S into the 3 x 3 ``Fe``, ``Se``."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = f
    s00, s11, s22, s01, s02, s12 = s
    Fe[0, 0], Fe[0, 1], Fe[0, 2] = f00, f01, f02
    Fe[1, 0], Fe[1, 1], Fe[1, 2] = f10, f11, f12
    Fe[2, 0], Fe[2, 1], Fe[2, 2] = f20, f21, f22
    Se[0, 0], Se[0, 1], Se[0, 2] = s00, s01, s02
    Se[1, 0], Se[1, 1], Se[1, 2] = s01, s11, s12
    Se[2, 0], Se[2, 1], Se[2, 2] = s02, s12, s22


@_step
def add_force(force, dofs, grads, e, v, f, s):  # type: ignore[no-untyped-def]
    """Add element ``e``'s internal force f_ai = P_iJ G_aJ, P = v F S, to ``force``."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = f
    s00, s11, s22, s01, s02, s12 = s
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


@_step
def cofactors(f):  # type: ignore[no-untyped-def]
    """adj(F), row-major, so that F^-1 = adj(F) / det F."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = f
    return (
        f11 * f22 - f12 * f21,
        f02 * f21 - f01 * f22,
        f01 * f12 - f02 * f11,
        f12 * f20 - f10 * f22,
        f00 * f22 - f02 * f20,
        f02 * f10 - f00 * f12,
        f10 * f21 - f11 * f20,
        f01 * f20 - f00 * f21,
        f00 * f11 - f01 * f10,
    )


@_step
def inverse(adj, J):  # type: ignore[no-untyped-def]
    """F^-1 = adj(F) / J, row-major (iF[I, i])."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = adj
    r = 1.0 / J
    return (a00 * r, a01 * r, a02 * r, a10 * r, a11 * r, a12 * r,
            a20 * r, a21 * r, a22 * r)  # fmt: skip


@_step
def gram(i):  # type: ignore[no-untyped-def]
    """The symmetric A A^T (00, 11, 22, 01, 02, 12) of a row-major A: C^-1 of F^-1."""
    i00, i01, i02, i10, i11, i12, i20, i21, i22 = i
    return (
        i00 * i00 + i01 * i01 + i02 * i02,
        i10 * i10 + i11 * i11 + i12 * i12,
        i20 * i20 + i21 * i21 + i22 * i22,
        i00 * i10 + i01 * i11 + i02 * i12,
        i00 * i20 + i01 * i21 + i02 * i22,
        i10 * i20 + i11 * i21 + i12 * i22,
    )


# --- the loops -------------------------------------------------------------------


@_jit
def svk_kinematics(  # type: ignore[no-untyped-def]
    u, modulus, dofs, grads, volumes, lam, mu, F, S, det, force
):
    """The loops of :func:`idbench_fem.fem.kernels.svk_kinematics`, in place.

    Arguments as its, with the outputs F, S (r, T, 3, 3), det (r, T) and
    force (r, n, zeros) last.
    """
    r, T = modulus.shape
    ue = np.empty(12)
    for q in range(r):
        uq, fq = u[q], force[q]
        for e in range(T):
            gather(uq, dofs, e, ue)
            h00, h01, h02, h10, h11, h12, h20, h21, h22 = gradient(ue, grads, e, 0.0)
            # Green-Lagrange strain E = (H + H^T + H^T H) / 2
            strain = (
                h00 + 0.5 * (h00 * h00 + h10 * h10 + h20 * h20),
                h11 + 0.5 * (h01 * h01 + h11 * h11 + h21 * h21),
                h22 + 0.5 * (h02 * h02 + h12 * h12 + h22 * h22),
                0.5 * (h01 + h10 + h00 * h01 + h10 * h11 + h20 * h21),
                0.5 * (h02 + h20 + h00 * h02 + h10 * h12 + h20 * h22),
                0.5 * (h12 + h21 + h01 * h02 + h11 * h12 + h21 * h22),
            )
            s = svk_stress(strain, modulus[q, e], lam, mu)
            f00, f11, f22 = h00 + 1.0, h11 + 1.0, h22 + 1.0
            f = (f00, h01, h02, h10, f11, h12, h20, h21, f22)
            store(F[q, e], S[q, e], f, s)
            det[q, e] = (
                f00 * (f11 * f22 - h12 * h21)
                - h01 * (h10 * f22 - h12 * h20)
                + h02 * (h10 * h21 - f11 * h20)
            )
            add_force(fq, dofs, grads, e, volumes[e], f, s)


@_jit
def law_kinematics(  # type: ignore[no-untyped-def]
    code, u, modulus, dofs, grads, volumes, lam, mu, F, S, det, force
):
    """The loops of :func:`idbench_fem.fem.law_kernels.law_kinematics`, in place."""
    T = len(modulus)
    ue = np.empty(12)
    for e in range(T):
        gather(u, dofs, e, ue)
        f = gradient(ue, grads, e, 1.0)
        f00, f01, f02, f10, f11, f12, f20, f21, f22 = f
        adj = cofactors(f)
        J = f00 * adj[0] + f01 * adj[3] + f02 * adj[6]
        det[e] = J
        m = modulus[e]
        if code == 0:  # St Venant-Kirchhoff: S = lambda tr(E) I + 2 mu E
            strain = (
                0.5 * (f00 * f00 + f10 * f10 + f20 * f20 - 1.0),
                0.5 * (f01 * f01 + f11 * f11 + f21 * f21 - 1.0),
                0.5 * (f02 * f02 + f12 * f12 + f22 * f22 - 1.0),
                0.5 * (f00 * f01 + f10 * f11 + f20 * f21),
                0.5 * (f00 * f02 + f10 * f12 + f20 * f22),
                0.5 * (f01 * f02 + f11 * f12 + f21 * f22),
            )
            s = svk_stress(strain, m, lam, mu)
        else:  # neo-Hookean: S = mu (I - C^-1) + lambda ln J C^-1
            lnJ = np.log(J) if J > 0.0 else np.nan
            c00, c11, c22, c01, c02, c12 = gram(inverse(adj, J))  # C^-1
            c = lam * lnJ - mu  # S = mu I + c C^-1
            s = (
                m * (mu + c * c00),
                m * (mu + c * c11),
                m * (mu + c * c22),
                m * (c * c01),
                m * (c * c02),
                m * (c * c12),
            )
        store(F[e], S[e], f, s)
        add_force(force, dofs, grads, e, volumes[e], f, s)


@_jit
def law_tangent(  # type: ignore[no-untyped-def]
    code, F, S, det, modulus, grads, volumes, lam, mu, emap, data
):
    """The loops of :func:`idbench_fem.fem.law_kernels.law_tangent`, into ``data``."""
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
            f = (Fe[0, 0], Fe[0, 1], Fe[0, 2], Fe[1, 0], Fe[1, 1], Fe[1, 2],
                 Fe[2, 0], Fe[2, 1], Fe[2, 2])  # fmt: skip
            inv = inverse(cofactors(f), J)  # iF[I, i]
            i00, i01, i02, i10, i11, i12, i20, i21, i22 = inv
            c00, c11, c22, c01, c02, c12 = gram(inv)
            M[0, 0], M[1, 1], M[2, 2] = c00, c11, c22
            M[0, 1] = M[1, 0] = c01
            M[0, 2] = M[2, 0] = c02
            M[1, 2] = M[2, 1] = c12
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
