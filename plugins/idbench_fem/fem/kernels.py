r"""Compiled St Venant-Kirchhoff element kernel (numba, optional).

One pass over the elements gives everything a Newton residual needs: the
deformation gradient F = I + H, the second Piola-Kirchhoff stress
S = E_e (lambda tr(E) I + 2 mu E) with E = (H + H^T + H^T H) / 2, det F, and
the assembled internal force f_a = V F S G_a on the free degrees of freedom
(lambda and mu at unit modulus, E_e the element's modulus). It is the maths of
:meth:`idbench_fem.fem.svk_assembly.Assembler.kinematics` and
:meth:`~idbench_fem.fem.svk_assembly.Assembler.forces` without their ~40 numpy calls
of a few thousand elements each: about 11x faster at 500-1,100 nodes
(``benchmarks/kernel.py``), equal to round-off (tests/test_skfem_kernels.py).
A residual is half of a batched sigma point's cost, so this is what brings a
RO-UKF step nearer to one forward step.

numba is optional (the ``fast`` extra, also in ``test``): without it, if it
does not import (it refuses a NumPy newer than it supports), or with
``IDBENCH_NUMBA=0``, the assembler uses its numpy path. Compiled code is
cached on disk (numba's ``cache=True``: next to this file, else in the user's
cache folder; without either, each process compiles), so only the first
process on a machine pays the compilation (about a second).
"""

from __future__ import annotations

import functools
import importlib.util
import logging
import os
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

ENV = "IDBENCH_NUMBA"
"""Set to 0 to use the numpy kernels even where numba is installed."""


def available() -> bool:
    """Whether the compiled kernel is used: numba works and is not switched off."""
    if os.environ.get(ENV, "1").strip() == "0":
        return False
    return _numba_works()


@functools.cache
def _numba_works() -> bool:
    """Whether numba imports (it refuses a NumPy newer than it supports)."""
    if importlib.util.find_spec("numba") is None:
        return False
    try:
        import numba  # noqa: F401
    except Exception as exc:  # numba's own check of its dependencies
        log.warning("numba does not import (%s); using the numpy kernels", exc)
        return False
    return True


def svk_kinematics(
    state: FloatArray,
    modulus: FloatArray,
    dofs: NDArray[np.int64],
    grads: FloatArray,
    volumes: FloatArray,
    lam: float,
    mu: float,
    n_free: int,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """F, S, det F and the internal force of every state of a stack.

    Parameters
    ----------
    state
        Free displacements (n,) or a stack (r, n).
    modulus
        Young's modulus per element (T,), or per state (r, T).
    dofs
        Free dof of each element's 12 nodal components, -1 if fixed (T, 12).
    grads, volumes
        Shape-function gradients (T, 4, 3) and volumes (T,).
    lam, mu
        Lamé parameters at unit modulus.
    n_free
        Number of free dofs n.

    Returns
    -------
    tuple
        F and S (..., T, 3, 3), det (..., T), force (..., n), with the leading
        axis of ``state`` (none for one state).
    """
    single = np.ndim(state) == 1
    # fresh, writable C arrays: the kernel indexes without bounds checks, and
    # numba compiles one version per array layout and writability
    u2 = np.array(state, dtype=np.float64, order="C", ndmin=2)
    if u2.ndim != 2 or u2.shape[1] != n_free:
        raise ValueError(
            f"state has shape {np.shape(state)}, expected ({n_free},) or (r, {n_free})"
        )
    r, T = len(u2), len(dofs)
    mod = np.empty((r, T))
    mod[...] = modulus  # (T,) or (r, T); anything else raises here
    F = np.empty((r, T, 3, 3))
    S = np.empty((r, T, 3, 3))
    det = np.empty((r, T))
    force = np.zeros((r, n_free))
    _compiled()(u2, mod, dofs, grads, volumes, lam, mu, F, S, det, force)
    if single:
        return F[0], S[0], det[0], force[0]
    return F, S, det, force


@functools.cache
def _compiled() -> Callable[..., Any]:
    """The numba kernel, compiled (or loaded from numba's cache) on first use."""
    import numba

    try:
        return numba.njit(cache=True, nogil=True)(_svk_loop)  # type: ignore[no-any-return]
    except RuntimeError as exc:  # nowhere writable to cache: compile each process
        log.warning("numba cannot cache the kernel (%s); compiling it here", exc)
        return numba.njit(nogil=True)(_svk_loop)  # type: ignore[no-any-return]


def _svk_loop(  # type: ignore[no-untyped-def]
    u, modulus, dofs, grads, volumes, lam, mu, F, S, det, force
):
    """The kernel's loops, writing its outputs in place.

    Compiled by numba (plain Python is far too slow). Arguments as
    :func:`svk_kinematics`'s, with the outputs F, S (r, T, 3, 3), det (r, T)
    and force (r, n, zeros) last.
    """
    r, T = modulus.shape
    ue = np.empty(12)
    for q in range(r):
        for e in range(T):
            for c in range(12):
                d = dofs[e, c]
                ue[c] = u[q, d] if d >= 0 else 0.0
            h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = 0.0
            for a in range(4):
                g0, g1, g2 = grads[e, a, 0], grads[e, a, 1], grads[e, a, 2]
                x, y, z = ue[3 * a], ue[3 * a + 1], ue[3 * a + 2]
                h00 += x * g0
                h01 += x * g1
                h02 += x * g2
                h10 += y * g0
                h11 += y * g1
                h12 += y * g2
                h20 += z * g0
                h21 += z * g1
                h22 += z * g2
            # Green-Lagrange strain E = (H + H^T + H^T H) / 2
            e00 = h00 + 0.5 * (h00 * h00 + h10 * h10 + h20 * h20)
            e11 = h11 + 0.5 * (h01 * h01 + h11 * h11 + h21 * h21)
            e22 = h22 + 0.5 * (h02 * h02 + h12 * h12 + h22 * h22)
            e01 = 0.5 * (h01 + h10 + h00 * h01 + h10 * h11 + h20 * h21)
            e02 = 0.5 * (h02 + h20 + h00 * h02 + h10 * h12 + h20 * h22)
            e12 = 0.5 * (h12 + h21 + h01 * h02 + h11 * h12 + h21 * h22)
            m = modulus[q, e]
            tr = lam * (e00 + e11 + e22)
            s00 = m * (2.0 * mu * e00 + tr)
            s11 = m * (2.0 * mu * e11 + tr)
            s22 = m * (2.0 * mu * e22 + tr)
            s01 = m * (2.0 * mu * e01)
            s02 = m * (2.0 * mu * e02)
            s12 = m * (2.0 * mu * e12)
            f00, f11, f22 = h00 + 1.0, h11 + 1.0, h22 + 1.0
            Fq, Sq = F[q, e], S[q, e]
            Fq[0, 0], Fq[0, 1], Fq[0, 2] = f00, h01, h02
            Fq[1, 0], Fq[1, 1], Fq[1, 2] = h10, f11, h12
            Fq[2, 0], Fq[2, 1], Fq[2, 2] = h20, h21, f22
            Sq[0, 0], Sq[0, 1], Sq[0, 2] = s00, s01, s02
            Sq[1, 0], Sq[1, 1], Sq[1, 2] = s01, s11, s12
            Sq[2, 0], Sq[2, 1], Sq[2, 2] = s02, s12, s22
            det[q, e] = (
                f00 * (f11 * f22 - h12 * h21)
                - h01 * (h10 * f22 - h12 * h20)
                + h02 * (h10 * h21 - f11 * h20)
            )
            # first Piola-Kirchhoff stress times the volume, P = V F S
            v = volumes[e]
            p00 = v * (f00 * s00 + h01 * s01 + h02 * s02)
            p01 = v * (f00 * s01 + h01 * s11 + h02 * s12)
            p02 = v * (f00 * s02 + h01 * s12 + h02 * s22)
            p10 = v * (h10 * s00 + f11 * s01 + h12 * s02)
            p11 = v * (h10 * s01 + f11 * s11 + h12 * s12)
            p12 = v * (h10 * s02 + f11 * s12 + h12 * s22)
            p20 = v * (h20 * s00 + h21 * s01 + f22 * s02)
            p21 = v * (h20 * s01 + h21 * s11 + f22 * s12)
            p22 = v * (h20 * s02 + h21 * s12 + f22 * s22)
            for a in range(4):
                g0, g1, g2 = grads[e, a, 0], grads[e, a, 1], grads[e, a, 2]
                d = dofs[e, 3 * a]
                if d >= 0:
                    force[q, d] += p00 * g0 + p01 * g1 + p02 * g2
                d = dofs[e, 3 * a + 1]
                if d >= 0:
                    force[q, d] += p10 * g0 + p11 * g1 + p12 * g2
                d = dofs[e, 3 * a + 2]
                if d >= 0:
                    force[q, d] += p20 * g0 + p21 * g1 + p22 * g2
