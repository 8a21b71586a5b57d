"""Timing of the estimators on the scikit-fem beam.

Prints, for a ~500-node model (default ``bend-y``, K = 20, noise 1e-4, an
observation every step):

- the RO-UKF's wall time per step divided by (p + 1) x one forward solve
  (target <= 1.1: the filter itself adds almost nothing), where one forward
  solve is the mean wall time of ``model.step`` along the same path with E_true
  (warm start from the previous step, as the filter does);
- the share of the RO-UKF's time spent outside ``model.step``;
- its steps per second (target >= 60 on one core);
- the full UKF's wall time and forward solves per step as multiples of the
  RO-UKF's on a ~240-node model (capped at a few steps: 2n + 1 solves each).

Run ``python benchmarks/filters.py`` (``--quick`` for small meshes). Set
OMP_NUM_THREADS / MKL_NUM_THREADS = 1 for the one-core figures.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import idbench
from idbench import ModelSpec, Observation, Prior
from idbench_filters import RoUkf, Ukf

E_TRUE = 5000.0
PRIOR = Prior((2500.0,), (2500.0,))


class Timed:
    """Proxy that times ``step`` calls of a forward model."""

    def __init__(self, model):
        self._model = model
        self.step_seconds = 0.0

    def __getattr__(self, name):
        return getattr(self._model, name)

    def step(self, theta, k, state, *, substeps=1):
        t = time.perf_counter()
        try:
            return self._model.step(theta, k, state, substeps=substeps)
        finally:
            self.step_seconds += time.perf_counter() - t


def build(mesh: str, scenario: str, n_steps: int):
    reg = idbench.build_registry()
    spec = ModelSpec(mesh=mesh, scenario=reg.scenario(scenario), n_steps=n_steps)
    return reg.model("svk-beam")(spec)


def truth_path(model, noise: float, seed: int = 0):
    """Observations with E_true plus noise, and the mean time of one step."""
    rng = np.random.default_rng(seed)
    its0 = model.cost().newton_its
    u = model.reset()
    obs, seconds = {}, []
    for k in range(1, model.n_steps + 1):
        t = time.perf_counter()
        u = model.step(np.array([E_TRUE]), k, u)
        seconds.append(time.perf_counter() - t)
        y = model.observe(u) + noise * rng.normal(size=model.observe(u).shape)
        obs[k] = Observation(values=y, noise_std=noise, step=k)
    its = (model.cost().newton_its - its0) / model.n_steps
    return obs, float(np.mean(seconds)), its


def time_filter(est, model, obs, n_steps: int, repeats: int = 1):
    """Best-of-``repeats`` (wall seconds a step, step seconds a step, solves a step)."""
    best = None
    for _ in range(repeats):
        timed = Timed(model)
        est.start(timed, PRIOR)
        t = time.perf_counter()
        for k in range(1, n_steps + 1):
            e = est.update(k, obs.get(k))
        wall = (time.perf_counter() - t) / n_steps
        row = (wall, timed.step_seconds / n_steps, e.cost.forward_solves / n_steps)
        if best is None or row[0] < best[0]:
            best = row
    return best, e


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default="500")
    parser.add_argument("--ukf-mesh", default="240")
    parser.add_argument("--scenario", default="bend-y")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--ukf-steps", type=int, default=2)
    parser.add_argument("--noise", type=float, default=1e-4)
    parser.add_argument("--quick", action="store_true", help="small meshes")
    args = parser.parse_args()
    if args.quick:
        args.mesh, args.ukf_mesh, args.steps = "10x2x2", "6x1x1", 10

    model = build(args.mesh, args.scenario, args.steps)
    obs, t_solve, its_truth = truth_path(model, args.noise)
    p = model.parameters.p
    # interleave reference solves and filter runs (machine load drifts); best of 3
    best = None
    for _ in range(3):
        _, t, _ = truth_path(model, args.noise)
        t_solve = min(t_solve, t)
        row, e = time_filter(RoUkf(), model, obs, args.steps)
        if best is None or row[0] < best[0][0]:
            best = (row, e)
    (wall, in_step, solves), est = best
    print(
        f"RO-UKF (simplex) on {args.mesh!r}: {model.n_state} dofs, p = {p}, "
        f"K = {args.steps}, scenario {args.scenario}"
    )
    print(f"  one forward solve (mean along the path)  {1e3 * t_solve:8.2f} ms")
    print(
        f"  RO-UKF wall per step                     {1e3 * wall:8.2f} ms "
        f"({solves:.0f} solves)"
    )
    print(
        f"  ratio wall / ((p+1) x solve)             {wall / ((p + 1) * t_solve):8.3f}"
        "   (target <= 1.1)"
    )
    its_filter = est.cost.newton_its / est.cost.forward_solves
    print(f"  Newton its per solve: path {its_truth:.2f}, RO-UKF {its_filter:.2f}")
    print(f"  share outside model.step                 {1 - in_step / wall:8.3f}")
    print(
        f"  steps per second                         {1 / wall:8.1f}   (target >= 60)"
    )
    print(f"  final estimate E = {est.mean[0]:.1f} +- {est.std[0]:.1f}")

    small = build(args.ukf_mesh, args.scenario, args.steps)
    obs_s, _, _ = truth_path(small, args.noise)
    (ro_wall, _, ro_solves), _ = time_filter(RoUkf(), small, obs_s, args.steps, 3)
    ukf = Ukf(max_solves=10**6)
    (uk_wall, _, uk_solves), _ = time_filter(ukf, small, obs_s, args.ukf_steps)
    print(
        f"Full UKF vs RO-UKF on {args.ukf_mesh!r}: {small.n_state} dofs "
        f"(UKF over its first {args.ukf_steps} steps)"
    )
    print(
        f"  solves per step  UKF {uk_solves:8.0f}  RO-UKF {ro_solves:4.0f}  "
        f"x{uk_solves / ro_solves:.0f}"
    )
    print(
        f"  wall per step    UKF {uk_wall:8.2f} s  RO-UKF {1e3 * ro_wall:.2f} ms  "
        f"x{uk_wall / ro_wall:.0f}"
    )


if __name__ == "__main__":
    main()
