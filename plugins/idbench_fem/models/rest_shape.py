r"""The stress-free shape of a body imaged under a known load (inverse elastostatics).

A mesh built from a scan is the organ as it was imaged: already deformed by
gravity. Taking it as the rest shape makes the truth and the model start
loaded. The stress-free reference X is the shape that the load deforms into
the imaged one x*: :math:`\varphi(X) = X + u(X) = x^*`, with u(X) the
equilibrium displacement of the body meshed at X under that load. Sellier's
fixed point (Sellier 2011, "An iterative method for the inverse
elasto-static problem", J. Fluids Struct. 27) finds it by moving the
reference by the mismatch,

.. math::

    X_0 = x^*, \qquad X_{i+1} = X_i + (x^* - \varphi(X_i)),

which converges linearly (about as fast as |grad u| is small) and needs only
forward solves. Each iteration solves the load on the mesh at X_i by the
model's own Newton (the first along the model's load ramp, later ones from
the previous iteration's displacement, which is close). It stops when
:math:`\max_a |x^*_a - \varphi(X_i)_a|` is below ``tolerance`` (m).

In a body TOML (:mod:`idbench_fem.bodies.reference`)::

    [reference]
    imaged_under = "sag"   # a manipulation: the meshes are the shape under it
    tolerance = 1e-5       # m (default), on the re-loaded shape
    max_iterations = 30

and every mesh of the body (the truth's, the models', the reference the
markers are placed on) is replaced by its stress-free shape
(:func:`rest_mesh`), so every manipulation starts unloaded; the one named
ends at the imaged shape.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench import ModelFailure
from idbench_fem.bodies.description import Body
from idbench_fem.bodies.mesh import SolidMesh, check_not_folded

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class RestShape:
    """The result of :func:`stress_free`.

    Attributes
    ----------
    points
        The stress-free node coordinates X (N, 3).
    mismatch
        max_a |x*_a - phi(X)_a| (m) after each iteration.
    """

    points: FloatArray
    mismatch: tuple[float, ...]


def stress_free(
    build: Any,
    imaged: FloatArray,
    *,
    tolerance: float = 1e-5,
    max_iterations: int = 30,
) -> RestShape:
    """Sellier's fixed point: the X whose loaded shape is ``imaged`` (N, 3).

    Parameters
    ----------
    build
        ``build(points)`` -> a solid model of the body meshed at ``points``
        under the imaging load (its last load step is the whole load).
    imaged
        The imaged node coordinates x* (N, 3).
    tolerance, max_iterations
        Stop when the re-loaded shape is within ``tolerance`` (m) of x*.

    Raises
    ------
    ValueError
        No convergence in ``max_iterations``, or a reference with inverted
        tets (one line, with the mismatch reached).
    """
    target = np.asarray(imaged, dtype=float)
    X = target.copy()
    u = None
    history: list[float] = []
    for _ in range(max_iterations):
        model = build(X)
        theta = np.asarray(model.parameters.default, dtype=float)
        u = _loaded(model, theta, u)
        moved = X + model.displacement_field(u)
        gap = target - moved
        history.append(float(np.linalg.norm(gap, axis=1).max()))
        if history[-1] <= tolerance:
            return RestShape(X, tuple(history))
        X = X + gap
    raise ValueError(
        f"stress-free reference: the re-loaded shape is still {history[-1]:.3g} m "
        f"from the imaged one after {max_iterations} iterations (tolerance "
        f"{tolerance:g} m; mismatches {', '.join(f'{h:.2g}' for h in history[-3:])})"
    )


def _loaded(model: Any, theta: FloatArray, start: FloatArray | None) -> FloatArray:
    """The state under the whole load: along the ramp, or from ``start``."""
    K = model.n_steps
    if start is not None:
        try:
            return np.asarray(model.step(theta, K, start, substeps=1))
        except ModelFailure:
            pass  # far from the last iteration's: along the ramp
    u = model.reset()
    for k in range(1, K + 1):
        u = model.step(theta, k, u)
    return np.asarray(u)


def rest_mesh(body: Body, mesh: SolidMesh, settings: Any = None) -> SolidMesh:
    """``mesh`` at its stress-free shape if ``body`` says it was imaged under load.

    Without ``[reference]`` the mesh itself. Computed once per (body, mesh,
    law and nu settings) in a process.
    """
    if body.reference is None:
        return mesh
    law = getattr(settings, "law", None)
    nu = getattr(settings, "nu", None)
    return _rest_mesh(body, mesh, law, nu)


@functools.lru_cache(maxsize=16)
def _rest_mesh(body: Body, mesh: SolidMesh, law: Any, nu: Any) -> SolidMesh:
    from idbench_fem.models.solid import SolidModel
    from idbench_fem.models.solid_settings import SolidSettings

    ref = body.reference
    assert ref is not None
    settings = SolidSettings(law=law, nu=nu, path_reuse=False)

    def build(points: FloatArray) -> SolidModel:  # its points placed on the image
        moved = dataclasses.replace(mesh, points=points)
        return SolidModel(body, moved, ref.imaged_under, mesh, ref.steps, 1, settings)

    shape = stress_free(
        build, mesh.points, tolerance=ref.tolerance,
        max_iterations=ref.max_iterations,
    )  # fmt: skip
    path = f"{mesh.path} (stress-free under {ref.imaged_under})"
    check_not_folded(shape.points, mesh.tets, path)
    log.info(
        "%s: stress-free reference in %d iterations (mismatch %.2g m)",
        mesh.path, len(shape.mismatch), shape.mismatch[-1],
    )  # fmt: skip
    out = dataclasses.replace(mesh, points=shape.points, path=path)
    out.points.flags.writeable = False
    return out
