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

import sys
from pathlib import Path

import numpy as np
from _timing import best_of, one_blas_thread, parser, ratio

from idbench_fem.bodies import box as meshes
from idbench_fem.models.beam import build
from idbench_fem.models.beam_scenarios import SCENARIOS

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.oracles.v01_kernel import old_element_tangents


def best(f, repeat=20):
    """Least wall time (s) of ``repeat`` calls."""
    return best_of(f, repeat)[0]


def row(size: str) -> None:
    """Time the kernels at step 10 of bend-y on the mesh ``size``; print one row."""
    m = build(meshes.parse(size), SCENARIOS[0], n_steps=20)
    theta = np.array([5000.0])
    u = m.reset()
    for k in range(1, 11):
        u = m.step(theta, k, u)
    asm = m._asm
    mod = np.full(asm.n_elements, 5000.0)
    kin = asm.kinematics(u, mod)
    t_old = best(lambda: old_element_tangents(asm, kin, mod))
    t_new = best(lambda: asm.element_tangent_blocks(kin, mod, out=asm._blocks))
    t_data = best(lambda: asm.tangent_data(kin, mod, m._pattern))
    compiled, asm.compiled = asm.compiled, False
    t_kf = best(lambda: asm.forces(asm.kinematics(u, mod)))
    asm.compiled = compiled
    t_kc = np.nan
    if compiled:  # numba installed and not switched off
        t_kc = best(lambda: asm.forces(asm.kinematics(u, mod)))
    data = asm.tangent_data(kin, mod, m._pattern)
    t_fac = best(lambda: m._solver.factor(data), 10)
    print(
        f"{m.n_nodes:>6} {asm.n_elements:>6} | {1e3 * t_old:>7.2f} "
        f"{1e3 * t_new:>7.2f} {ratio(t_old, t_new, 1):>5} | {1e3 * t_data:>12.2f} | "
        f"{1e3 * t_kf:>8.2f} {1e3 * t_kc:>8.3f} {ratio(t_kf, t_kc, 1):>5} | "
        f"{1e3 * t_fac:>9.2f}"
    )


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--sizes", nargs="*", default=["525", "1116", "4000"])
    args = ap.parse_args()
    print(
        f"{'nodes':>6} {'tets':>6} | {'old ms':>7} {'new ms':>7} {'x':>5} | "
        f"{'tangent_data':>12} | {'kin+f ms':>8} {'compiled':>8} {'x':>5} | "
        f"{'factor ms':>9}"
    )
    with one_blas_thread():
        for size in args.sizes:
            row(size)


if __name__ == "__main__":
    main()
