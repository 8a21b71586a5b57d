"""Parameter fields: MAP + Laplace on the kidney, the localized ETKF on the liver.

Two cases, each a copy of the shipped body with an inclusion field
(:mod:`idbench_fem.bodies.field`; contrast 3, radius 12 mm) and a
displacement-controlled probe over it, seen by a depth-camera cloud (400
points) and the probe's force, 10 load steps, every step observed:

- the kidney at about 2,000 nodes with 200 cells: one ``map-laplace`` run
  (start, the K updates: Gauss-Newton with adjoint gradients and the
  Laplace posterior at the end), its wall time (target: under 10 s), its
  Gauss-Newton iterations, forward steps and back-substitutions;
- the liver at about 1,000 nodes with 50 cells: ``local-etkf`` (20 and 10
  members, localization 4 cm), its steps per second (target: >= 10 Hz) and
  its factorizations a step (each member's own);

each beside the bound ``B`` = one assembly, factorization and solve of the
model's tangent at the path's end, measured in the same run: a run's wall
time as a multiple of B says what the machine does not. The data come from
the model mesh itself (this times the estimators, it does not score them).

Run ``python benchmarks/fields.py`` (``--quick``: 500-node kidney with 50
cells, 4 steps).
Set OMP_NUM_THREADS / MKL_NUM_THREADS / OPENBLAS_NUM_THREADS = 1 for
one-core figures.
"""

from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path

import numpy as np
from _timing import one_blas_thread, parser

import idbench
from idbench import ModelSpec, Observation, Prior, Scenario
from idbench.core.observation_model import Frame
from idbench.observe.cloud import Cloud
from idbench.observe.kinds import Combined, Force
from idbench.observe.observed_model import ObservedModel
from idbench_fem.bodies.catalog import body_path
from idbench_filters import LocalizedEtkf, MapLaplace

CASES = {
    "kidney": {"centre": (0.02, 0.003, 0.0), "probe": (0.02, 0.003, 0.02),
               "push": (0.0, 0.0, -0.004), "camera": (0.02, 0.0, 0.2)},
    "liver": {"centre": (0.05, 0.01, 0.0), "probe": (0.05, 0.04, 0.0),
              "push": (0.0, -0.004, 0.0), "camera": (0.05, 0.25, 0.0)},
}  # fmt: skip


def field_body(folder: Path, body: str, cells: int) -> Path:
    """The shipped ``body`` with an inclusion field and a probe over it."""
    case = CASES[body]
    src = body_path(body)
    text = re.sub(r"(?m)^E_regions.*\n", "", src.read_text())
    text = re.sub(r"(?ms)^\[parameters\].*?(?=^\[|\Z)", "", text)
    text = text.replace('"meshes/', f'"{src.parent}/meshes/')
    probe = (f'\n[[manipulation]]\nname = "probe"\nkind = "grasp"\n'
             f"point = {list(case['probe'])}\nradius = 0.012\n"
             f"displacement = {list(case['push'])}\n")  # fmt: skip
    text = text.replace("\n[markers]", probe + "\n[markers]", 1)
    sphere = f"{{ sphere = {{ centre = {list(case['centre'])}, radius = 0.012 }} }}"
    text += (f"\n[field]\ncells = {cells}\nlength = 0.015\nstd = 0.5\n"
             f"[[field.inclusion]]\nregion = {sphere}\ncontrast = 3.0\n")  # fmt: skip
    path = folder / f"{body}-field.toml"
    path.write_text(text)
    return path


def observed(body: str, mesh: str, cells: int, steps: int):
    """The model seen through cloud + force, its data, its truth path and prior."""
    with tempfile.TemporaryDirectory() as tmp:
        path = field_body(Path(tmp), body, cells)
        load = {"body": str(path), "manipulation": "probe"}
        spec = ModelSpec(mesh=mesh, scenario=Scenario("probe", load), n_steps=steps,
                         settings={"body": str(path), "reference": mesh})  # fmt: skip
        model = idbench.build_registry().model("solid")(spec)
    true = np.array(model.parameters.default)
    cloud = Cloud(points=400, noise=2e-4, position=CASES[body]["camera"],
                  look_at=CASES[body]["centre"])  # fmt: skip
    force = Force(noise=1e-3)
    obs = Combined((("cloud", cloud), ("force", force)))
    rng = np.random.default_rng(0)
    u, frames = model.reset(), []
    for k in range(1, steps + 1):
        u = model.step(true, k, u)
        c = cloud.measure([cloud.sense(model, true, k, u)], rng, 2e-4)[0]
        f = force.measure([force.sense(model, true, k, u)], rng, 1e-3)[0]
        frames.append(Frame(k, Combined.merge([("cloud", c), ("force", f)])))
    seen = ObservedModel(model, obs, frames)
    data = [Observation(obs.values(f), obs.noise_std(f, 2e-4), f.step) for f in frames]
    E = float(np.median(true))
    return model, seen, data, true, u, Prior.broadcast(E, E / 2, len(true))


def bound(model, theta, u) -> float:
    """Seconds of one assembly, factorization and solve at ``u`` (best of 3)."""
    modulus = model.element_moduli(theta, model.n_steps)
    asm = model.assembler
    if hasattr(asm, "unknown"):  # a driven probe: its dofs are not unknowns
        asm.values = u[asm.prescribed]
        u = u[asm.unknown]
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        model.factor(asm.kinematics(u, modulus), modulus, model.n_steps)
        model.solve(np.ones(len(u)))
        best = min(best, time.perf_counter() - start)
    return best


def run(estimator, seen, data, prior) -> float:
    """Wall seconds of one run (start and every update)."""
    start = time.perf_counter()
    estimator.start(seen, prior)
    for obs in data:
        estimator.update(obs.step, obs)
    return time.perf_counter() - start


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="small meshes, 4 steps")
    args = ap.parse_args()
    steps = 4 if args.quick else 10
    kidney = ("500", 50) if args.quick else ("2000", 200)
    liver = ("500", 20) if args.quick else ("1000", 50)
    model, seen, data, true, u, prior = observed("kidney", kidney[0], kidney[1], steps)
    B = bound(model, true, u)
    print(f"kidney {model.n_nodes} nodes, {model.parameters.p} cells, {steps} steps, "
          f"cloud+force ({len(data[0].values)} values a step): B = {1e3 * B:.1f} ms")
    est = MapLaplace()
    c0 = model.cost()
    wall = run(est, seen, data, prior)
    cost = model.cost() - c0
    print(f"  map-laplace: {wall:.2f} s a run = {wall / B:.0f} B (target < 10 s); "
          f"{est.iterations} Gauss-Newton iterations, {cost.forward_solves} forward "
          f"steps, {cost.linear_solves} back-substitutions")  # fmt: skip
    model, seen, data, true, u, prior = observed("liver", liver[0], liver[1], steps)
    B = bound(model, true, u)
    print(f"liver {model.n_nodes} nodes, {model.parameters.p} cells: B = "
          f"{1e3 * B:.1f} ms")
    for members in (20, 10):
        est = LocalizedEtkf(members=members, localization=0.04, init="random")
        f0 = model.factorizations
        wall = run(est, seen, data, prior)
        factored = (model.factorizations - f0) / steps
        print(f"  local-etkf ({members} members): {steps / wall:.1f} Hz = one step "
              f"in {wall / steps / B:.1f} B (target >= 10 Hz); "
              f"{factored:.1f} factorizations a step")  # fmt: skip


if __name__ == "__main__":
    with one_blas_thread():
        main()
