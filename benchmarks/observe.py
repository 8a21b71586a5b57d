"""The cost of observing by point cloud (issue 27's targets).

1. One cloud prediction h(x) (the deformed surface and each point's gated
   signed distance to it, :mod:`idbench.depth_camera`) of ``--points``
   points on the liver at about ``--nodes`` nodes, per sigma point (target
   <= 1 ms for 2,000 points on ~1,000 nodes): best of ``--repeat`` means.
2. The RO-UKF step with clouds against the same step with markers (the
   liver's 8), on the same model and load path (target <= 1.2x), steps 2..K
   of ``--steps`` (the first pays for one-off set-ups).

The frames come from the model itself at the true E (this measures cost, not
accuracy). Run ``python benchmarks/observe.py`` or ``--quick`` (a 9x2x2 beam,
100 points: only checks that the script works).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import idbench
from idbench import observe
from idbench.depth_camera import Cloud
from idbench.observed_model import ObservedModel
from idbench_filters.ro_ukf import RoUkf


def build(quick: bool, nodes: int, steps: int):  # type: ignore[no-untyped-def]
    reg = idbench.build_registry()
    if quick:
        spec = idbench.ModelSpec("9x2x2", reg.scenario("bend-y"), n_steps=steps)
        return reg.model("svk-beam")(spec)
    settings = {"body": "liver", "reference": str(nodes)}
    spec = idbench.ModelSpec(
        str(nodes), reg.scenario("grasp-lift"), n_steps=steps, markers=8,
        settings=settings,
    )  # fmt: skip
    return reg.model("solid")(spec)


def frames(model, cloud: Cloud, theta, states):  # type: ignore[no-untyped-def]
    clean = [cloud.sense(model, theta, k, s) for k, s in enumerate(states, 1)]
    data = cloud.measure(clean, np.random.default_rng(0), 1e-3)
    return [observe.Frame(k, d) for k, d in enumerate(data, 1)]


def run_filter(model, stream) -> list[float]:  # type: ignore[no-untyped-def]
    est = RoUkf()
    est.start(model, idbench.Prior.broadcast(2000.0, 2000.0, model.parameters.p))
    times = []
    for k, obs in enumerate(stream, start=1):
        t0 = time.perf_counter()
        est.update(k, obs)
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--nodes", type=int, default=1000)
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    points = 100 if args.quick else args.points
    model = build(args.quick, args.nodes, args.steps)
    theta = np.array(model.parameters.default or (5000.0,), dtype=float)
    u, states = model.reset(), []
    for k in range(1, model.n_steps + 1):
        u = model.step(theta, k, u)
        states.append(u)
    _, T = model.surface(states[-1])
    cloud = Cloud(points=points)
    fr = frames(model, cloud, theta, states)
    k = model.n_steps
    best, cpu = np.inf, np.inf
    for _ in range(args.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(20):
            cloud.predict(model, fr[-1], theta, k, states[-1])
        best = min(best, (time.perf_counter() - t0) / 20)
        cpu = min(cpu, (time.process_time() - c0) / 20)
    print(
        f"cloud h(x): {points} points, {model.n_nodes} nodes, {len(T)} surface "
        f"triangles: {1e3 * best:.3f} ms per sigma point (CPU {1e3 * cpu:.3f} ms; "
        "target <= 1 ms)"
    )
    rng = np.random.default_rng(1)
    markers = [
        idbench.Observation(model.observe(s) + 1e-4 * rng.standard_normal(
            model.observe(s).shape), 1e-4, k)
        for k, s in enumerate(states, 1)
    ]  # fmt: skip
    clouds = [idbench.Observation(np.zeros(points), 1e-3, k) for k in range(1, k + 1)]
    wrapped = ObservedModel(model, cloud, fr)
    t_m, t_c = [], []
    for _ in range(max(1, args.repeat // 2)):
        t_m.append(np.sum(run_filter(model, markers)[1:]))
        t_c.append(np.sum(run_filter(wrapped, clouds)[1:]))
    n = model.n_steps - 1
    m, c = min(t_m) / n, min(t_c) / n
    print(
        f"RO-UKF step: markers {1e3 * m:.1f} ms, cloud {1e3 * c:.1f} ms: "
        f"ratio {c / m:.2f} (target <= 1.2)"
    )


if __name__ == "__main__":
    main()
