"""Element tangent kernel: the blocked, elements-last kernel against the v0.1 one.

Times, at the state of load step 10 of the bend-y path, the v0.1 kernel (12 x 12
element matrices as B^T D B by batched matmul, reproduced here) and
:meth:`Assembler.element_tangent_blocks` (10 node-pair blocks, elements last),
plus the full ``tangent_data`` (kernel and scatter to CSR) and, for scale, the
kinematics + internal force (a Newton residual) with numpy and with the
compiled kernel (:mod:`idbench_fem.fem.kernels`, if numba is installed) and one
PARDISO factorization. Best of 20; ratios against the old kernel and the
numpy residual in the same run.

Run ``python benchmarks/kernel.py [--sizes 525 1116 4000]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from idbench_fem.bodies import box as meshes
from idbench_fem.models.beam import build
from idbench_fem.models.beam_scenarios import SCENARIOS


def old_element_tangents(asm, kin, modulus):
    """The v0.1 kernel, (T, 12, 12)."""
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


def best(f, repeat=20):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="*", default=["525", "1116", "4000"])
    args = ap.parse_args()
    print(
        f"{'nodes':>6} {'tets':>6} | {'old ms':>7} {'new ms':>7} {'x':>5} | "
        f"{'tangent_data':>12} | {'kin+f ms':>8} {'compiled':>8} {'x':>5} | "
        f"{'factor ms':>9}"
    )
    for size in args.sizes:
        m = build(meshes.parse(size), SCENARIOS[0], n_steps=20)
        theta = np.array([5000.0])
        u = m.reset()
        for k in range(1, 11):
            u = m.step(theta, k, u)
        asm = m._asm
        mod = np.full(asm.n_elements, 5000.0)
        kin = asm.kinematics(u, mod)
        t_old = best(lambda: old_element_tangents(asm, kin, mod))  # noqa: B023
        t_new = best(lambda: asm.element_tangent_blocks(kin, mod, out=asm._blocks))  # noqa: B023
        t_data = best(lambda: asm.tangent_data(kin, mod, m._pattern))  # noqa: B023
        compiled, asm.compiled = asm.compiled, False
        t_kf = best(lambda: asm.forces(asm.kinematics(u, mod)))  # noqa: B023
        asm.compiled = compiled
        t_kc = np.nan
        if compiled:  # numba installed and not switched off
            t_kc = best(lambda: asm.forces(asm.kinematics(u, mod)))  # noqa: B023
        data = asm.tangent_data(kin, mod, m._pattern)
        t_fac = best(lambda: m._solver.factor(data), 10)  # noqa: B023
        print(
            f"{m.n_nodes:>6} {asm.n_elements:>6} | {1e3 * t_old:>7.2f} "
            f"{1e3 * t_new:>7.2f} {t_old / t_new:>4.1f}x | {1e3 * t_data:>12.2f} | "
            f"{1e3 * t_kf:>8.2f} {1e3 * t_kc:>8.3f} {t_kf / t_kc:>4.1f}x | "
            f"{1e3 * t_fac:>9.2f}"
        )


if __name__ == "__main__":
    main()
