"""FElupe's side of the forward benchmarks: a quasi-static load path on a beam.

The same Newton path the forward and solid benchmarks race against: the beam's
tet mesh as a FElupe region (one quadrature point), x = lower end clamped,
nodal point loads, PARDISO (pypardiso) for the linear systems and our residual
test (||residual on free dofs|| <= the step's tolerance) as FElupe's ``check``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import felupe as fem
import numpy as np
import pypardiso
from _timing import best_of


@dataclass
class FelupePath:
    """A timed FElupe path: best time (s), final field, Newton iterations.

    ``solid`` and ``dof1`` (the free dofs) are kept for timings at the end state.
    """

    time: float
    field: Any
    its: int
    solid: Any
    dof1: Any


def felupe_path(
    beam: Any,
    material: Any,
    nodal_loads: Callable[[int], np.ndarray],
    tols: Sequence[float],
    repeat: int = 2,
) -> FelupePath:
    """Time the path of nodal loads ``nodal_loads(k)`` (N, 3), k = 1..K.

    One warm-up run, then the best of ``repeat``.

    ``tols[k - 1]`` is step k's residual tolerance; the nodes loaded at step K
    carry the point loads.
    """
    n_steps = len(tols)
    region = fem.RegionTetra(fem.Mesh(beam.points, beam.tets, "tetra"))
    field = fem.FieldContainer([fem.Field(region, dim=3)])
    solid = fem.SolidBody(material, field)
    bounds = {"clamped": fem.dof.Boundary(field[0], fx=beam.lower[0])}
    dof0, dof1 = fem.dof.partition(field, bounds)
    loaded = np.flatnonzero(np.abs(nodal_loads(n_steps)).sum(axis=1))
    load = fem.PointLoad(field, loaded)
    its = [0]

    def run():
        field.link(fem.FieldContainer([fem.Field(region, dim=3)]))
        x = field
        its[0] = 0
        for k in range(1, n_steps + 1):
            load.values = nodal_loads(k)[loaded]
            tol = tols[k - 1]

            def check(dx, x, f, xtol, ftol, dof1=None, dof0=None, items=None, tol=tol):
                fnorm = float(np.linalg.norm(f[dof1]))
                return float(np.linalg.norm(dx)), fnorm, fnorm <= tol

            res = fem.newtonraphson(
                x, items=[solid, load], dof1=dof1, dof0=dof0, solver=pypardiso.spsolve,
                check=check, verbose=0, maxiter=25,
            )  # fmt: skip
            if not res.success:
                raise RuntimeError(f"FElupe did not converge at step {k}")
            x = res.x
            its[0] += res.iterations
        return x

    run()
    t, x = best_of(run, repeat)
    return FelupePath(t, x, its[0], solid, dof1)
