r"""Compiled St Venant-Kirchhoff element kernel (numba, optional).

One pass over the elements gives everything a Newton residual needs: the
deformation gradient F = I + H, the second Piola-Kirchhoff stress
S = E_e (lambda tr(E) I + 2 mu E) with E = (H + H^T + H^T H) / 2, det F, and
the assembled internal force f_a = V F S G_a on the free degrees of freedom
(lambda and mu at unit modulus, E_e the element's modulus). It is the maths of
:meth:`idbench_fem.fem.svk_assembly.Assembler.kinematics` and
:meth:`~idbench_fem.fem.svk_assembly.Assembler.forces` without their ~40 numpy calls
of a few thousand elements each: about 11x faster at 500-1,100 nodes
(``benchmarks/kernel.py``), equal to round-off (tests/fem/test_kernels.py).
Its loops (:mod:`~.element_loops`) share their per-element steps with the
general-law kernels (:mod:`~.law_kernels`). A residual is half of a batched
sigma point's cost, so this is what brings a RO-UKF step nearer to one forward
step.

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
from types import ModuleType
from typing import Protocol

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


class Elements(Protocol):
    """What the compiled kernels read of an assembler (a ``TetAssembly``).

    Attributes
    ----------
    element_dofs
        Free dof of each element's 12 nodal components, -1 if fixed (T, 12).
    grads, volumes
        Shape-function gradients (T, 4, 3) and volumes (T,).
    lam, mu
        Lamé parameters at unit modulus.
    n_free
        Number of free dofs n.
    """

    element_dofs: NDArray[np.int64]
    grads: FloatArray
    volumes: FloatArray
    lam: float
    mu: float
    n_free: int


def svk_kinematics(
    state: FloatArray, modulus: FloatArray, elements: Elements
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """F, S, det F and the internal force of every state of a stack.

    Parameters
    ----------
    state
        Free displacements (n,) or a stack (r, n).
    modulus
        Young's modulus per element (T,), or per state (r, T).
    elements
        The mesh's dofs, gradients, volumes and Lamé parameters.

    Returns
    -------
    tuple
        F and S (..., T, 3, 3), det (..., T), force (..., n), with the leading
        axis of ``state`` (none for one state).
    """
    n_free, dofs = elements.n_free, elements.element_dofs
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
    loops().svk_kinematics(u2, mod, dofs, elements.grads, elements.volumes,
                           elements.lam, elements.mu, F, S, det, force)  # fmt: skip
    if single:
        return F[0], S[0], det[0], force[0]
    return F, S, det, force


def loops() -> ModuleType:
    """The compiled loops (:mod:`~.element_loops`), imported on first use.

    Call only where :func:`available`; numba compiles each loop (or loads it
    from its cache) on its first call.
    """
    from idbench_fem.fem import element_loops

    return element_loops
