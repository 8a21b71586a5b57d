"""Timing of the estimators on the scikit-fem beam, with and without step_many.

Prints, on the bend-y path (K = 20, noise 1e-4, an observation every step):

- for the RO-UKF (simplex) at each ``--meshes`` size with p = 1, and at the
  first size with p = 4 regions: one forward solve (mean wall time of
  ``model.step`` along the path with E_true, warm started as the filter is),
  the filter's wall time a step with the sigma points batched through
  ``model.step_many`` and looped through ``model.step`` (the model without
  ``step_many``), and for p = 4 also batched with ``--processes`` (model
  option ``processes``: helper processes take shares of the sigma points),
  each as a multiple of one forward solve over the whole path and over its
  second half (targets: <= 1.3 for p = 1, <= 2 for p = 4), steps per second,
  and tangent factorizations a step (the helpers' included);
- the same RO-UKF rows for two organs of the ``solid`` model at
  ``--organ-mesh`` nodes (``--no-organs``: skip them): the liver lifted by a
  grasper (neo-Hookean, p = 1) and the kidney pulled at its pole (E of the
  parenchyma and of the tumour, p = 2, also with ``--processes``), each from a
  prior at 0.6 x its true moduli with a standard deviation of half of them;
- the full UKF's wall time a step over its first ``--ukf-steps`` steps,
  batched and looped, at each ``--ukf-meshes`` size (target 10x).

All figures are best of ``--repeat`` runs interleaved in the same process, so
their ratios hold on a loaded machine; absolute times do not. Run
``python benchmarks/filters.py`` (``--quick`` for small meshes). BLAS runs one
thread (one-core figures: on a shared 2-core machine the threaded eigh of the
full UKF's covariance is several times slower than the single-threaded one).
"""

from __future__ import annotations

import importlib.util
import time

import numpy as np
from _timing import one_blas_thread, parser, ratio

import idbench
from idbench import ModelSpec, Observation, Prior
from idbench.registry.testing import WithoutStepMany
from idbench_filters import RoUkf, Ukf

E_TRUE = 5000.0


def build(mesh: str, scenario: str, n_steps: int, p: int = 1, processes: int = 1):
    reg = idbench.build_registry()
    settings = {"parameters": "E_regions", "regions": p} if p > 1 else {}
    if processes > 1:
        settings["processes"] = processes
    kw = {"settings": settings} if settings else {}
    spec = ModelSpec(mesh=mesh, scenario=reg.scenario(scenario), n_steps=n_steps, **kw)
    return reg.model("svk-beam")(spec)


def organ(body: str, manipulation: str, mesh: str, n_steps: int, processes: int = 1):
    """A ``solid`` model of a shipped body (its meshes are made on first use)."""
    reg = idbench.build_registry()
    settings = {"body": body, "reference": mesh, "processes": processes}
    spec = ModelSpec(
        mesh=mesh, scenario=reg.scenario(manipulation), n_steps=n_steps,
        settings=settings,
    )  # fmt: skip
    return reg.model("solid")(spec)


def truth_path(model, noise: float, seed: int = 0, theta=None):
    """Observations with ``theta`` (default E_true) plus noise, and the mean
    time of one step."""
    rng = np.random.default_rng(seed)
    if theta is None:
        theta = np.full(model.parameters.p, E_TRUE)
    u = model.reset()
    obs, seconds = {}, []
    for k in range(1, model.n_steps + 1):
        t = time.perf_counter()
        u = model.step(theta, k, u)
        seconds.append(time.perf_counter() - t)
        y = model.observe(u) + noise * rng.normal(size=model.observe(u).shape)
        obs[k] = Observation(values=y, noise_std=noise, step=k)
    return obs, float(np.mean(seconds))


def time_filter(est, model, obs, n_steps: int, prior=None):
    """Wall seconds a step (mean over all steps, and over the second half),
    tangent factorizations a step and the last estimate."""
    p = model.parameters.p
    counted = model.model if isinstance(model, WithoutStepMany) else model  # a view
    f0 = counted.factorizations
    est.start(model, prior or Prior((2500.0,) * p, (2500.0,) * p))
    seconds = []
    for k in range(1, n_steps + 1):
        t = time.perf_counter()
        e = est.update(k, obs.get(k))
        seconds.append(time.perf_counter() - t)
    wall, late = float(np.mean(seconds)), float(np.mean(seconds[n_steps // 2 :]))
    return wall, (counted.factorizations - f0) / n_steps, e, late


def ro_ukf_rows(label, make, args, theta=None, prior=None):
    """Time the RO-UKF on ``make(processes)``'s model: batched, looped and,
    for p > 1, with ``--processes``."""
    model = make(1)
    p = model.parameters.p
    obs, t_solve = truth_path(model, args.noise, theta=theta)
    variants = {"batched": model, "looped": WithoutStepMany(model)}
    if p > 1 and args.processes > 1:
        # sigma points shared with helper processes (one run first starts them)
        two = make(args.processes)
        time_filter(RoUkf(), two, obs, 1, prior)
        variants[f"{args.processes} procs"] = two
    best = {name: (np.inf,) for name in variants}
    for _ in range(args.repeat):  # interleaved: machine load drifts
        t_solve = min(t_solve, truth_path(model, args.noise, theta=theta)[1])
        for name, m in variants.items():
            row = time_filter(RoUkf(), m, obs, args.steps, prior)
            if row[0] < best[name][0]:
                best[name] = row
    print(
        f"RO-UKF simplex, {label} ({model.n_nodes} nodes, {model.n_state} dofs), "
        f"p = {p}: one forward solve {1e3 * t_solve:.2f} ms"
    )
    for name in variants:
        wall, fac, e, late = best[name]
        print(
            f"  {name:8s} {1e3 * wall:8.2f} ms a step = {wall / t_solve:5.2f} x solve"
            f" (second half {late / t_solve:4.2f})  {1 / wall:6.1f} Hz"
            f"  {fac:5.1f} factorizations a step  E = {e.mean[0]:.2f}"
        )
    print(f"  step_many speed-up {ratio(best['looped'][0], best['batched'][0])}")
    for m in variants.values():
        getattr(m, "close", lambda: None)()


def organ_rows(args):
    """The RO-UKF on the liver (grasp-lift) and the kidney (grasp-pole)."""
    for body, manipulation in (("liver", "grasp-lift"), ("kidney", "grasp-pole")):

        def make(processes, body=body, manipulation=manipulation):
            return organ(body, manipulation, args.organ_mesh, args.steps, processes)

        theta = np.array(make(1).parameters.default)
        prior = Prior(tuple(0.6 * theta), tuple(0.5 * theta))
        label = f"{body} {manipulation} {args.organ_mesh!r}"
        ro_ukf_rows(label, make, args, theta, prior)


def ukf_rows(mesh, args):
    model = build(mesh, args.scenario, args.steps)
    obs, _ = truth_path(model, args.noise)
    ukf = Ukf(max_solves=10**6)
    wall_b, _, eb, _ = time_filter(ukf, model, obs, args.ukf_steps)
    wall_l, _, el, _ = time_filter(ukf, WithoutStepMany(model), obs, args.ukf_steps)
    diff = abs(eb.mean[0] / el.mean[0] - 1)
    print(
        f"Full UKF on {mesh!r} ({model.n_nodes} nodes, {2 * model.n_state + 3} "
        f"sigma points), first {args.ukf_steps} steps: batched {wall_b:.3f} s a "
        f"step, looped {wall_l:.3f} s a step, speed-up {ratio(wall_l, wall_b, 1)} "
        f"(E differs by {diff:.1e})"
    )


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--meshes", nargs="*", default=["20x4x4", "30x5x5"])
    ap.add_argument("--ukf-meshes", nargs="*", default=["9x2x2", "14x3x3"])
    ap.add_argument("--scenario", default="bend-y")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--ukf-steps", type=int, default=2)
    ap.add_argument("--regions", type=int, default=4)
    ap.add_argument(
        "--processes", type=int, default=2, help="for p > 1 also with this many"
    )
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--noise", type=float, default=1e-4)
    ap.add_argument("--organ-mesh", default="1000", help="organ mesh spec")
    ap.add_argument("--no-organs", action="store_true", help="skip the organs")
    ap.add_argument("--quick", action="store_true", help="small meshes")
    args = ap.parse_args()
    if args.quick:
        args.meshes, args.ukf_meshes, args.steps = ["10x2x2"], ["6x1x1"], 10
        args.organ_mesh = "200"
    with one_blas_thread():
        for i, mesh in enumerate(args.meshes):
            for p in (1, args.regions) if i == 0 and args.regions > 1 else (1,):

                def make(processes, mesh=mesh, p=p):
                    return build(mesh, args.scenario, args.steps, p, processes)

                ro_ukf_rows(repr(mesh), make, args)
        if not args.no_organs:
            if importlib.util.find_spec("gmsh") is None:
                print("organs skipped: their meshes need gmsh (pip install gmsh)")
            else:
                organ_rows(args)
        for mesh in args.ukf_meshes:
            ukf_rows(mesh, args)


if __name__ == "__main__":
    main()
