"""Forward-model speed: our SVK Newton solve against FElupe's, same problem.

Both solve the same load path (the bend-y end traction in a few load steps) on
the same tet mesh with the same nodal load, one quadrature point per element,
St Venant-Kirchhoff (FElupe: a ``felupe.Material`` with vectorised SVK stress
and elasticity, total Lagrange -- FElupe's ``LinearElasticLargeStrain`` is a
compressible neo-Hookean in FElupe 11 and its built-in SVK needs tensortrax),
PARDISO (pypardiso) for the linear systems and the same convergence test
(||residual on free dofs|| <= our tolerance; FElupe gets it as its ``check``).
Printed per mesh size: wall time of each, ratio, Newton iterations, agreement
of the displacement fields, and per-iteration assembly / factorization / solve
times measured separately; then, at the largest mesh, our Newton time divided
by its linear algebra alone (factorizations x factorization time + iterations x
solve time): what assembly and Python add. Our Newton keeps a factorization
for chord steps where the residual fell 100x (``chord_ratio``), so it factors
less often than it iterates; FElupe factors every iteration.

Run ``python benchmarks/forward.py`` (about 250, 1,000, 4,000, 11,000 nodes) or
``--quick`` (250 and 1,000).
"""

from __future__ import annotations

import felupe as fem
import numpy as np
import pypardiso
from _felupe import felupe_path
from _timing import best_of, model_path, node_counts, one_blas_thread, ratio

from idbench_fem.bodies import box as meshes
from idbench_fem.bodies.loads import traction_forces
from idbench_fem.bodies.regions import region_facets
from idbench_fem.models.beam import build
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_fem.models.beam_settings import BeamSettings, EndTraction

E, NU = 5000.0, 0.45
N_STEPS = 4
SIZES = (250, 1000, 4000, 11000)
QUICK = (250, 1000)
SCENARIO = SCENARIOS[0]  # bend-y


def svk_material(E, nu):
    """St Venant-Kirchhoff for FElupe: P = F S and A = dP/dF, arrays (3, 3, q, c)."""
    lmbda = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    eye = np.eye(3)

    def green_stress(F):
        H = F - eye[:, :, None, None]
        E_ = 0.5 * (
            H + np.einsum("ji...->ij...", H) + np.einsum("ki...,kj...->ij...", H, H)
        )
        tr = np.einsum("ii...->...", E_)
        return 2 * mu * E_ + lmbda * tr * eye[:, :, None, None]

    def stress(x, **kwargs):
        F, statevars = x[0], x[-1]
        return [np.einsum("iJ...,JL...->iL...", F, green_stress(F)), statevars]

    def elasticity(x, **kwargs):
        F = x[0]
        S = green_stress(F)
        FFt = np.einsum("iJ...,kJ...->ik...", F, F)
        A = np.einsum("ik,JL...->iJkL...", eye, S)
        A += lmbda * np.einsum("iJ...,kL...->iJkL...", F, F)
        A += mu * np.einsum("ik...,JL->iJkL...", FFt, eye)
        A += mu * np.einsum("iL...,kJ...->iJkL...", F, F)
        return [A]

    return fem.Material(stress, elasticity)


def ours(beam):
    model = build(
        beam, SCENARIO, N_STEPS, settings=BeamSettings(nu=NU, solver="pardiso")
    )
    run = model_path(model, np.array([E]))
    c0, f0 = model.cost(), model.factorizations
    t, u = best_of(run, 3)
    its = (model.cost() - c0).newton_its // 3
    factors = (model.factorizations - f0) // 3
    tol = [
        model.rtol * np.linalg.norm(model.external_force(k))
        for k in range(1, N_STEPS + 1)
    ]

    asm, pat, solver = model._asm, model._pattern, model._solver
    mod = np.full(asm.n_elements, E)
    reps = 5
    t_asm, _ = best_of(
        lambda: (
            asm.forces(kin := asm.kinematics(u, mod)),
            asm.tangent_data(kin, mod, pat),
        ),
        reps,
    )
    data = asm.tangent_data(asm.kinematics(u, mod), mod, pat)
    t_fac, _ = best_of(lambda: solver.factor(data), reps)
    t_sol, _ = best_of(lambda: solver.solve(data[: model.n_state] * 0 + 1.0), reps)
    return {
        "time": t, "its": its, "factors": factors,
        "u": model.displacement_field(u), "tol": tol,
        "asm": t_asm, "fac": t_fac, "sol": t_sol, "model": model,
    }  # fmt: skip


def felupe_solve(beam, tols):
    end = region_facets(beam, meshes.loaded_face(beam))
    w = traction_forces(beam, end, np.array([1.0, 0.0, 0.0]))[:, 0]  # area / 3

    def nodal_loads(k):
        return w[:, None] * EndTraction.of(SCENARIO).traction(k, N_STEPS)[None, :]

    path = felupe_path(beam, svk_material(E, NU), nodal_loads, tols)
    t, x, its, solid, dof1 = path.time, path.field, path.its, path.solid, path.dof1
    u = x[0].values.copy()
    # separate timings at the converged state
    t_asm, _ = best_of(lambda: (solid.assemble.vector(x), solid.assemble.matrix(x)), 3)
    K = solid.assemble.matrix(x).tocsr()[dof1][:, dof1].tocsr()
    b = np.ones(K.shape[0])

    flip = [K, K * (1 + 1e-15)]  # defeat pypardiso's "same matrix" shortcut

    def factor_solve():
        flip.reverse()
        pypardiso.spsolve(flip[0], b)  # FElupe's path: analysis + factor + solve

    t_fs, _ = best_of(factor_solve, 3)
    return {"time": t, "its": its, "u": u, "asm": t_asm, "fac_sol": t_fs}


def main():
    sizes = node_counts(__doc__, SIZES, QUICK)
    print(f"bend-y, {N_STEPS} load steps, E={E}, nu={NU}, PARDISO, 1 BLAS thread")
    head = (
        f"{'nodes':>6} {'dofs':>6} | {'ours s':>7} {'its':>3} {'asm ms':>7} "
        f"{'fac ms':>7} {'sol ms':>6} | {'FElupe s':>8} {'its':>3} {'asm ms':>7} "
        f"{'f+s ms':>7} | {'speed-up':>8} {'max|du|/max|u|':>14}"
    )
    print(head)
    print("-" * len(head))
    last = None
    with one_blas_thread():
        for n in sizes:
            beam = meshes.parse(str(n))
            a = ours(beam)
            b = felupe_solve(beam, a["tol"])
            diff = np.abs(a["u"] - b["u"]).max() / np.abs(b["u"]).max()
            print(
                f"{len(beam.points):>6} {a['model'].n_state:>6} | {a['time']:>7.3f} "
                f"{a['its']:>3} {1e3 * a['asm']:>7.1f} {1e3 * a['fac']:>7.1f} "
                f"{1e3 * a['sol']:>6.1f} | {b['time']:>8.3f} {b['its']:>3} "
                f"{1e3 * b['asm']:>7.1f} {1e3 * b['fac_sol']:>7.1f} | "
                f"{ratio(b['time'], a['time'], 1):>8} {diff:>14.1e}"
            )
            if diff > 1e-4:
                print(f"  WARNING: results differ beyond 4 digits ({diff:.1e})")
            last = a
    if last is not None:
        ideal = last["factors"] * last["fac"] + last["its"] * last["sol"]
        print(
            f"\nNewton at {len(last['u'])} nodes: {last['time']:.3f} s for "
            f"{last['its']} iterations ({last['factors']} factorizations, the "
            f"others chord steps);\nlinear algebra alone (factorizations x factor "
            f"+ iterations x solve) = {ideal:.3f} s; ratio {last['time'] / ideal:.2f} "
            f"(target <= 1.2: all the rest, assembly and Python, under 20%)"
        )


if __name__ == "__main__":
    main()
