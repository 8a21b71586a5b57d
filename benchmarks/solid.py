"""The ``solid`` model's speed: against svk-beam, and neo-Hookean against FElupe.

1. The cantilever as a body (a .vtu of the beam mesh, x = 0 fixed by a box,
   the bend-y traction on x = L by a box): the ``solid`` model (SVK, kernel
   ``auto``, i.e. the beam's assembler, and ``general``, the general-law one)
   against ``svk-beam`` on the same mesh, load and tolerance. Printed: wall
   time of the path (best of 3), the ratio solid / svk-beam (target <= 1.05)
   and the largest displacement difference.
2. The same body with the compressible neo-Hookean law against FElupe's
   ``NeoHookeCompressible`` (the same strain energy,
   W = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2), one quadrature point,
   PARDISO, the same residual test: times and the displacement agreement.

Run ``python benchmarks/solid.py`` (about 250, 1,000 and 4,000 nodes) or
``--quick`` (250 and 1,000).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import felupe as fem
import meshio
import numpy as np
import pypardiso

import idbench
from idbench_fem.bodies import box as meshes
from idbench_fem.models.beam import build
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_fem.models.beam_settings import BeamSettings, EndTraction
from idbench_fem.models.solid import make_model

E, NU = 5000.0, 0.45
N_STEPS = 4
SIZES = (250, 1000, 4000)
QUICK = (250, 1000)
SCENARIO = SCENARIOS[0]  # bend-y


def beam_body(beam, folder: Path, law: str) -> Path:
    """Write the beam mesh and a body TOML describing the cantilever."""
    mesh = folder / "beam.vtu"
    meshio.write(mesh, meshio.Mesh(beam.points, [("tetra", beam.tets)]))
    (x0, y0, z0), (x1, y1, z1) = beam.lower.tolist(), beam.upper.tolist()
    t = EndTraction.of(SCENARIO).traction(N_STEPS, N_STEPS).tolist()
    e = 1e-9

    def box(x):  # the nodes of the plane at x
        return (f"{{ lower = [{x - e}, {y0 - 1}, {z0 - 1}], "
                f"upper = [{x + e}, {y1 + 1}, {z1 + 1}] }}")  # fmt: skip

    text = f"""
[mesh]
truth = "beam.vtu"
[material]
law = "{law}"
E = {E}
nu = {NU}
[fixed]
box = {box(x0)}
[[manipulation]]
name = "end"
kind = "traction"
region = {{ box = {box(x1)} }}
traction = {t}
[markers]
points = [[{x1}, {y0}, {z1}], [{x1}, {y1}, {z1}]]
[shape_error]
grid = [8, 3, 3]
"""
    path = folder / f"beam-{law}.toml"
    path.write_text(text)
    return path


def best_of(f, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def path_runner(model):
    theta = np.array([E])

    def run():
        u = model.reset()
        for k in range(1, N_STEPS + 1):
            u = model.step(theta, k, u)
        return u

    run()  # symbolic analysis, caches
    return run


def race(models, repeat=7):
    """Best wall time of each model's path, runs interleaved (fair under load)."""
    runners = [path_runner(m) for m in models]
    best = [np.inf] * len(models)
    out = [None] * len(models)
    for _ in range(repeat):
        for i, run in enumerate(runners):
            t = time.perf_counter()
            out[i] = run()
            best[i] = min(best[i], time.perf_counter() - t)
    fields = [m.displacement_field(u) for m, u in zip(models, out, strict=True)]
    return best, fields


def solid(body, **settings):
    sc = idbench.Scenario("end", {"body": str(body), "manipulation": "end"})
    spec = idbench.ModelSpec("truth", sc, N_STEPS, 2, {"solver": "pardiso", **settings})
    return make_model(spec)


def felupe_neo_hooke(beam, model):
    m = fem.Mesh(beam.points, beam.tets, "tetra")
    region = fem.RegionTetra(m)
    field = fem.FieldContainer([fem.Field(region, dim=3)])
    lmbda = E * NU / ((1 + NU) * (1 - 2 * NU))
    mu = E / (2 * (1 + NU))
    body = fem.SolidBody(fem.NeoHookeCompressible(mu=mu, lmbda=lmbda), field)
    bounds = {"fixed": fem.dof.Boundary(field[0], fx=beam.lower[0])}
    dof0, dof1 = fem.dof.partition(field, bounds)
    f_end = model.displacement_field(model.external_force(N_STEPS))  # (N, 3)
    loaded = np.flatnonzero(np.abs(f_end).sum(axis=1))
    load = fem.PointLoad(field, loaded)
    its = [0]

    def run():
        field.link(fem.FieldContainer([fem.Field(region, dim=3)]))
        x = field
        its[0] = 0
        for k in range(1, N_STEPS + 1):
            load.values = (k / N_STEPS) * f_end[loaded]
            tol = model.rtol * np.linalg.norm(model.external_force(k))

            def check(dx, x, f, xtol, ftol, dof1=None, dof0=None, items=None, tol=tol):
                fnorm = float(np.linalg.norm(f[dof1]))
                return float(np.linalg.norm(dx)), fnorm, fnorm <= tol

            res = fem.newtonraphson(
                x, items=[body, load], dof1=dof1, dof0=dof0, check=check,
                solver=pypardiso.spsolve, verbose=0, maxiter=25,
            )  # fmt: skip
            if not res.success:
                raise RuntimeError(f"FElupe did not converge at step {k}")
            x = res.x
            its[0] += res.iterations
        return x

    run()
    t, x = best_of(run, 2)
    return t, x[0].values.copy(), its[0]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="only 250 and 1,000 nodes")
    ap.add_argument("--sizes", type=int, nargs="*", help="node-count targets")
    args = ap.parse_args()
    sizes = args.sizes or (QUICK if args.quick else SIZES)
    print(f"bend-y as a body, {N_STEPS} load steps, E={E}, nu={NU}, PARDISO")
    head = (
        f"{'nodes':>6} | {'svk-beam s':>10} {'solid s':>8} {'ratio':>6} "
        f"{'general s':>9} {'max|du|/|u|':>11} | {'NH s':>7} {'FElupe s':>8} "
        f"{'its':>7} {'max|du|/|u|':>11}"
    )
    print(head)
    print("-" * len(head))
    for n in sizes:
        beam = meshes.parse(str(n))
        with tempfile.TemporaryDirectory() as tmp:
            svk_body = beam_body(beam, Path(tmp), "svk")
            nh_body = beam_body(beam, Path(tmp), "neo-hookean")
            ref = build(
                beam, SCENARIO, N_STEPS, settings=BeamSettings(nu=NU, solver="pardiso")
            )
            models = [ref, solid(svk_body), solid(svk_body, kernel="general")]
            (t_beam, t_solid, t_gen), (u_beam, u_solid, u_gen) = race(models)
            scale = np.abs(u_beam).max()
            d_svk = max(np.abs(u_solid - u_beam).max(), np.abs(u_gen - u_beam).max())
            nh = solid(nh_body)
            c0 = nh.cost()
            (t_nh,), (u_nh,) = race([nh], repeat=3)
            its_nh = (nh.cost() - c0).newton_its // 4  # warm-up + 3 runs
            t_fe, u_fe, its_fe = felupe_neo_hooke(beam, nh)
            d_nh = np.abs(u_nh - u_fe).max() / np.abs(u_fe).max()
        print(
            f"{len(beam.points):>6} | {t_beam:>10.3f} {t_solid:>8.3f} "
            f"{t_solid / t_beam:>6.2f} {t_gen:>9.3f} {d_svk / scale:>11.1e} | "
            f"{t_nh:>7.3f} {t_fe:>8.3f} {its_nh:>3}/{its_fe:<3} {d_nh:>11.1e}"
        )
        if d_nh > 1e-6:
            print(f"  WARNING: neo-Hookean differs from FElupe by {d_nh:.1e}")


if __name__ == "__main__":
    main()
