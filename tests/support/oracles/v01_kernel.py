"""Test oracle and benchmark baseline: the v0.1 element tangent kernel.

The 12 x 12 element matrices as B^T D B by batched matmul, the kernel the
blocked, elements-last :meth:`Assembler.element_tangent_blocks` replaced: the
assembly tests check the new kernel against it and ``benchmarks/kernel.py``
times the two.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def old_element_tangents(asm: Any, kin: Any, modulus: FloatArray) -> FloatArray:
    """The v0.1 kernel: element tangents (T, 12, 12) of ``asm`` at ``kin``.

    Parameters
    ----------
    asm
        The beam's SVK assembler (``grads``, ``volumes``, ``mu``, ``lam``,
        ``n_elements``).
    kin
        Its kinematics at the state (``F`` and ``S``, per element).
    modulus
        Young's modulus per element, (T,).
    """
    G = asm.grads
    w = asm.volumes * modulus
    n = asm.n_elements
    Fs = kin.F * np.sqrt(2.0 * asm.mu * w)[:, None, None]
    Q = (
        Fs.transpose(0, 2, 1)[:, :, None, None, :]
        * G.transpose(0, 2, 1)[:, None, :, :, None]
    )
    B = np.empty((n, 7, 4, 3))
    for J in range(3):
        B[:, 1 + J] = Q[:, J, J]
    for c, (J, L) in enumerate(((0, 1), (0, 2), (1, 2))):
        np.add(Q[:, J, L], Q[:, L, J], out=B[:, 4 + c])
    B[:, 4:7] *= np.sqrt(0.5)
    np.sum(B[:, 1:4], axis=1, out=B[:, 0])
    B[:, 0] *= np.sqrt(abs(asm.lam) / (2.0 * asm.mu))
    B = B.reshape(n, 7, 12)
    Bt = np.ascontiguousarray(B.transpose(0, 2, 1))
    if asm.lam < 0:
        B = B * np.array([-1.0, 1, 1, 1, 1, 1, 1])[:, None]
    K = np.matmul(Bt, B)
    GS = np.matmul(G, kin.S * asm.volumes[:, None, None])
    GSG = np.matmul(GS, G.transpose(0, 2, 1))
    K5 = K.reshape(n, 4, 3, 4, 3)
    for i in range(3):
        K5[:, :, i, :, i] += GSG
    return K
