"""Step cost of the corrected RO-UKF over the uncorrected one (target: <= 1.2x).

On the scikit-fem beam at each ``--meshes`` size, on ``--scenario`` (K =
``--steps``, an observation every step, noise 1e-4): the approximation-error
discrepancy of the coarse mesh is calibrated against ``--fine`` (its fine
paths at the prior's 20% quantile, 30 steps, on ``--design``; cached like
truths), the observations are the fine mesh's path at E_true plus noise
(what a corrected filter sees), and the RO-UKF (simplex) runs the path
uncorrected on the coarse model and with ``correction =
"approximation-error"`` on the corrected one (:class:`CorrectedModel`).

Prints, per mesh: the CPU (process) and wall time a step of each (best of
``--repeat`` runs, the two interleaved in this process so that load drift
slows them alike; on a loaded machine the CPU time is the steadier one),
the ratio corrected / uncorrected, the estimates, and the corrected model's
own overhead a step (its observe, mean, Jacobian and covariance, timed
alone). Run ``python benchmarks/correction.py`` (``--quick``: small meshes).
BLAS runs one thread.
"""

from __future__ import annotations

import time

import numpy as np
from _timing import one_blas_thread, parser, ratio

import idbench
from idbench import ModelSpec, Observation, Prior
from idbench.calibrate.corrected import CorrectedModel
from idbench.calibrate.design import CalibrationSettings
from idbench.calibrate.fit import fit_discrepancy
from idbench_filters import RoUkf

E_TRUE = 5000.0
PRIOR = Prior((2500.0,), (2500.0,))


def spec(mesh: str, scenario: str, n_steps: int) -> ModelSpec:
    """The beam's model spec on ``mesh`` and ``scenario``."""
    reg = idbench.build_registry()
    return ModelSpec(mesh=mesh, scenario=reg.scenario(scenario), n_steps=n_steps)


def observations(mesh: str, scenario: str, n_steps: int, noise: float,
                 seed: int = 0) -> dict[int, Observation]:  # fmt: skip
    """The path on ``mesh`` at E_true, its markers plus seeded noise."""
    factory = idbench.build_registry().model("svk-beam")
    model = factory(spec(mesh, scenario, n_steps))
    rng = np.random.default_rng(seed)
    u, obs = model.reset(), {}
    theta = np.array([E_TRUE])
    for k in range(1, n_steps + 1):
        u = model.step(theta, k, u)
        y = np.asarray(model.observe(u), dtype=float)
        obs[k] = Observation(values=y + noise * rng.normal(size=y.shape),
                             noise_std=noise, step=k)  # fmt: skip
    return obs


def run_filter(est: RoUkf, model, obs: dict[int, Observation], n_steps: int):
    """Mean wall and CPU seconds a step of one run, and its last estimate."""
    est.start(model, PRIOR)
    wall, cpu = time.perf_counter(), time.process_time()
    for k in range(1, n_steps + 1):
        e = est.update(k, obs.get(k))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return wall / n_steps, cpu / n_steps, e


def overhead(corrected: CorrectedModel, model, n_steps: int) -> float:
    """Seconds a step of the correction's own work on the sigma points.

    Per step the RO-UKF observes its p + 1 = 2 sigma points through the
    corrected model and reads Sigma once at the mean: this times that work on
    the states of the uncorrected path at E_true.
    """
    u, states = model.reset(), []
    for k in range(1, n_steps + 1):
        u = model.step(np.array([E_TRUE]), k, u)
        states.append(u)
    start = time.process_time()
    for s in states:
        for _ in range(2):
            corrected.observe(s)
        corrected.observation_cov(s)
    return (time.process_time() - start) / n_steps


def mesh_rows(mesh: str, args) -> None:
    reg = idbench.build_registry()
    factory = reg.model("svk-beam")
    coarse = spec(mesh, args.scenario, args.steps)
    design = [reg.scenario(n) for n in args.design]
    settings = CalibrationSettings(quantile=0.2, scaled_steps=30)
    disc = fit_discrepancy(factory, coarse, args.fine, design, PRIOR, settings)
    obs = observations(args.fine, args.scenario, args.steps, args.noise)
    plain = factory(coarse)
    corrected = CorrectedModel(factory(coarse), disc, n_obs=len(obs))
    variants = {
        "uncorrected": (RoUkf(), plain),
        "corrected": (RoUkf(correction="approximation-error"), corrected),
    }
    for est, model in variants.values():  # warm: symbolic analysis, caches
        run_filter(est, model, obs, args.steps)
    wall, cpu = [np.inf, np.inf], [np.inf, np.inf]
    last = [None, None]
    for _ in range(args.repeat):  # interleaved: machine load drifts
        for i, (est, model) in enumerate(variants.values()):
            w, c, last[i] = run_filter(est, model, obs, args.steps)
            wall[i], cpu[i] = min(wall[i], w), min(cpu[i], c)
    extra = min(overhead(corrected, plain, args.steps) for _ in range(args.repeat))
    print(
        f"RO-UKF simplex, {mesh!r} ({plain.n_nodes} nodes), {args.scenario}, "
        f"K = {args.steps}; calibrated against {args.fine!r} on "
        f"{', '.join(args.design)} ({disc.cost:g} fine path simulations)"
    )
    for name, w, c, e in zip(variants, wall, cpu, last, strict=True):
        print(f"  {name:12s} {1e3 * c:8.2f} ms CPU ({1e3 * w:8.2f} ms wall) a step"
              f"  E = {e.mean[0]:8.1f}"
              f" (std {e.std[0]:.1f}), {e.cost.newton_its / args.steps:.1f} Newton"
              f" iterations a step")  # fmt: skip
    print(
        f"  corrected / uncorrected {ratio(cpu[1], cpu[0])} CPU, "
        f"{ratio(wall[1], wall[0])} wall (target <= 1.2x); the correction's own "
        f"work {1e3 * extra:.3f} ms CPU a step ({100 * extra / cpu[0]:.1f}% of "
        "the uncorrected step)"
    )


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--meshes", nargs="*", default=["14x3x3", "20x4x4"])
    ap.add_argument("--fine", default="40x6x6", help="calibration mesh spec")
    ap.add_argument("--design", nargs="*", default=["bend-y", "stretch-x", "bend-z"],
                    help="the calibration's scenarios")  # fmt: skip
    ap.add_argument("--scenario", default="mixed-30")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--noise", type=float, default=1e-4)
    ap.add_argument("--quick", action="store_true", help="small meshes")
    args = ap.parse_args()
    if args.quick:
        args.meshes, args.fine, args.steps, args.repeat = ["6x2x2"], "9x2x2", 8, 3
    with one_blas_thread():
        for mesh in args.meshes:
            mesh_rows(mesh, args)


if __name__ == "__main__":
    main()
