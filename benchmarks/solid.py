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
   PARDISO, the same residual test: times and the displacement agreement,
   and FElupe's time over the neo-Hookean path's (target >= 3), with the
   compiled kernels (:mod:`idbench_fem.fem.law_kernels`) and with the numpy
   ones (``IDBENCH_NUMBA=0`` when the model is built: the kernels before).

Run ``python benchmarks/solid.py`` (about 250, 1,000 and 4,000 nodes) or
``--quick`` (250 and 1,000).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import felupe as fem
import meshio
import numpy as np
from _felupe import felupe_path
from _timing import model_path, node_counts, one_blas_thread, race, ratio

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


def paths(models, repeat=7):
    """Best wall time of each model's path (interleaved) and its displacements."""
    best, out = race([model_path(m, np.array([E])) for m in models], repeat)
    fields = [m.displacement_field(u) for m, u in zip(models, out, strict=True)]
    return best, fields


def solid(body, **settings):
    sc = idbench.Scenario("end", {"body": str(body), "manipulation": "end"})
    spec = idbench.ModelSpec("truth", sc, N_STEPS, 2, {"solver": "pardiso", **settings})
    return make_model(spec)


def numpy_kernels(body):
    """The ``solid`` model of ``body`` with the numpy kernels (IDBENCH_NUMBA=0)."""
    old = os.environ.get("IDBENCH_NUMBA")
    os.environ["IDBENCH_NUMBA"] = "0"
    try:
        model = solid(body)
    finally:
        if old is None:
            del os.environ["IDBENCH_NUMBA"]
        else:
            os.environ["IDBENCH_NUMBA"] = old
    assert not model._asm.compiled
    return model


def felupe_neo_hooke(beam, model):
    lmbda = E * NU / ((1 + NU) * (1 - 2 * NU))
    mu = E / (2 * (1 + NU))
    f_end = model.displacement_field(model.external_force(N_STEPS))  # (N, 3)
    tols = [
        model.rtol * np.linalg.norm(model.external_force(k))
        for k in range(1, N_STEPS + 1)
    ]
    material = fem.NeoHookeCompressible(mu=mu, lmbda=lmbda)
    path = felupe_path(beam, material, lambda k: (k / N_STEPS) * f_end, tols)
    return path.time, path.field[0].values.copy(), path.its


def row(n):
    """Time and compare the models at about ``n`` nodes; print one row."""
    beam = meshes.parse(str(n))
    with tempfile.TemporaryDirectory() as tmp:
        svk_body = beam_body(beam, Path(tmp), "svk")
        nh_body = beam_body(beam, Path(tmp), "neo-hookean")
        ref = build(
            beam, SCENARIO, N_STEPS, settings=BeamSettings(nu=NU, solver="pardiso")
        )
        models = [ref, solid(svk_body), solid(svk_body, kernel="general")]
        (t_beam, t_solid, t_gen), (u_beam, u_solid, u_gen) = paths(models)
        scale = np.abs(u_beam).max()
        d_svk = max(np.abs(u_solid - u_beam).max(), np.abs(u_gen - u_beam).max())
        nh, nh_np = solid(nh_body), numpy_kernels(nh_body)
        c0 = nh.cost()
        (t_nh, t_np), (u_nh, _) = paths([nh, nh_np], repeat=3)
        its_nh = (nh.cost() - c0).newton_its // 4  # warm-up + 3 runs
        t_fe, u_fe, its_fe = felupe_neo_hooke(beam, nh)
        d_nh = np.abs(u_nh - u_fe).max() / np.abs(u_fe).max()
    print(
        f"{len(beam.points):>6} | {t_beam:>10.3f} {t_solid:>8.3f} "
        f"{ratio(t_solid, t_beam):>6} {t_gen:>9.3f} {d_svk / scale:>11.1e} | "
        f"{t_nh:>7.3f} {t_fe:>8.3f} {its_nh:>3}/{its_fe:<3} {d_nh:>11.1e} | "
        f"{ratio(t_fe, t_nh):>6} {t_np:>8.3f} {ratio(t_fe, t_np):>7}"
    )
    if d_nh > 1e-6:
        print(f"  WARNING: neo-Hookean differs from FElupe by {d_nh:.1e}")


def main():
    sizes = node_counts(__doc__, SIZES, QUICK)
    print(f"bend-y as a body, {N_STEPS} load steps, E={E}, nu={NU}, PARDISO, ", end="")
    print("1 BLAS thread")
    head = (
        f"{'nodes':>6} | {'svk-beam s':>10} {'solid s':>8} {'ratio':>6} "
        f"{'general s':>9} {'max|du|/|u|':>11} | {'NH s':>7} {'FElupe s':>8} "
        f"{'its':>7} {'max|du|/|u|':>11} | {'FE/NH':>6} {'numpy s':>8} {'FE/NHnp':>7}"
    )
    print(head)
    print("-" * len(head))
    with one_blas_thread():
        for n in sizes:
            row(n)


if __name__ == "__main__":
    main()
