"""The cost of observing by point cloud (against its targets).

1. One cloud prediction h(x) (each point's gated signed distance to the
   deformed surface, :func:`idbench.observe.surface.point_to_surface`) of
   ``--points`` points on the liver at about ``--nodes`` nodes, CPU time per
   sigma point (target <= 1 ms for 2,000 points on ~1,000 nodes): a fresh
   KD-tree query at every state (the cost before associations were reused)
   against the reused :class:`~idbench.observe.surface.Association`: a
   frame's first evaluation, its others (states at E x 0.97 and x 1.03, as
   sigma points), and their mean over the RO-UKF's p + 1 evaluations a
   frame; best of ``--repeat`` means.
2. The RO-UKF step (CPU time) with clouds against the same step with
   markers (the liver's 8), on the same model and load path (target <=
   1.2x), steps 2..K of ``--steps`` (the first pays for one-off set-ups);
   also with a fresh KD-tree query at every state.

The frames come from the model itself at the true E (this measures cost, not
accuracy). Run ``python benchmarks/observe.py`` or ``--quick`` (a 9x2x2 beam,
100 points: only checks that the script works).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import time

import numpy as np

import idbench
import idbench.observe.cloud
from idbench.observe import kinds
from idbench.observe.cloud import Cloud
from idbench.observe.observed_model import ObservedModel
from idbench.observe.surface import point_to_surface
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
    return [kinds.Frame(k, d) for k, d in enumerate(data, 1)]


SPREAD = (0.97, 1.03)
"""Sigma-point-like E factors: the states the other evaluations of a frame see."""


def sigma_like(model, theta, factors):  # type: ignore[no-untyped-def]
    """The model's path at each ``theta * f``."""
    out = []
    for f in factors:
        u, path = model.reset(), []
        for k in range(1, model.n_steps + 1):
            u = model.step(theta * f, k, u)
            path.append(u)
        out.append(path)
    return out


def per_sigma_point(model, fr, paths, repeat):  # type: ignore[no-untyped-def]
    """CPU s of one h(x): a frame's first, its others, and a fresh query's.

    Each repeat evaluates every frame at each path's state of its step (the
    first path first), on fresh copies of the points (so a frame's first
    evaluation builds its association); best of ``repeat`` means.
    """
    first = later = fresh = np.inf
    for _ in range(repeat):
        t_first = t_later = t_fresh = 0.0
        for f in fr:
            points = f.data["points"].copy()
            for i, path in enumerate(paths):
                V, T = model.surface(path[f.step - 1])
                c0 = time.process_time()
                point_to_surface(points, V, T, gate=5e-3)
                c1 = time.process_time()
                point_to_surface(points, V, T, gate=5e-3, reuse=False)
                c2 = time.process_time()
                t_fresh += c2 - c1
                if i == 0:
                    t_first += c1 - c0
                else:
                    t_later += c1 - c0
        n = len(fr)
        first = min(first, t_first / n)
        later = min(later, t_later / (n * (len(paths) - 1)))
        fresh = min(fresh, t_fresh / (n * len(paths)))
    return first, later, fresh


def run_filter(model, stream) -> list[float]:  # type: ignore[no-untyped-def]
    est = RoUkf()
    est.start(model, idbench.Prior.broadcast(2000.0, 2000.0, model.parameters.p))
    times = []
    for k, obs in enumerate(stream, start=1):
        t0 = time.process_time()
        est.update(k, obs)
        times.append(time.process_time() - t0)
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
    near = sigma_like(model, theta, SPREAD)
    first, later, fresh = per_sigma_point(model, fr, [states, *near], args.repeat)
    r = 1 + model.parameters.p  # RO-UKF's simplex sigma points per frame
    mean = (first + (r - 1) * later) / r
    print(
        f"cloud h(x): {points} points, {model.n_nodes} nodes, {len(T)} surface "
        f"triangles, CPU ms per sigma point: fresh KD-tree query {1e3 * fresh:.3f}; "
        f"reused association: a frame's first {1e3 * first:.3f}, its others "
        f"{1e3 * later:.3f}, mean over RO-UKF's {r} a frame {1e3 * mean:.3f} "
        f"(ratio {mean / fresh:.2f}; target <= 1 ms)"
    )
    k = model.n_steps
    rng = np.random.default_rng(1)
    markers = [
        idbench.Observation(model.observe(s) + 1e-4 * rng.standard_normal(
            model.observe(s).shape), 1e-4, k)
        for k, s in enumerate(states, 1)
    ]  # fmt: skip
    clouds = [idbench.Observation(np.zeros(points), 1e-3, k) for k in range(1, k + 1)]
    t_m, t_c, t_f = [], [], []
    for _ in range(max(1, args.repeat // 2)):
        t_m.append(np.sum(run_filter(model, markers)[1:]))
        wrapped = ObservedModel(model, cloud, copied(fr))
        t_c.append(np.sum(run_filter(wrapped, clouds)[1:]))
        with fresh_queries():
            wrapped = ObservedModel(model, cloud, copied(fr))
            t_f.append(np.sum(run_filter(wrapped, clouds)[1:]))
    n = model.n_steps - 1
    m, c, f = min(t_m) / n, min(t_c) / n, min(t_f) / n
    print(
        f"RO-UKF step: markers {1e3 * m:.1f} ms, cloud {1e3 * c:.1f} ms (ratio "
        f"{c / m:.2f}; target <= 1.2), cloud with a fresh query at every state "
        f"{1e3 * f:.1f} ms (ratio {f / m:.2f})"
    )


def copied(fr):  # type: ignore[no-untyped-def]
    """The frames with new arrays (no association built yet)."""
    return [kinds.Frame(f.step, {k: v.copy() for k, v in f.data.items()}) for f in fr]


@contextlib.contextmanager
def fresh_queries():  # type: ignore[no-untyped-def]
    """Clouds query a fresh KD-tree at every state (the cost before reuse)."""
    original = idbench.observe.cloud.point_to_surface  # what Cloud.predict calls
    idbench.observe.cloud.point_to_surface = functools.partial(original, reuse=False)
    try:
        yield
    finally:
        idbench.observe.cloud.point_to_surface = original


if __name__ == "__main__":
    main()
