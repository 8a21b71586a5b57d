r"""The offline half of a reduced model: design paths, POD, ECSW, the disk cache.

A reduced model is asked for like a mesh (``--meshes rom:16000:40``, see
:func:`parse_spec`). Offline, for the body's ``[design]``
(:mod:`idbench_fem.bodies.design`):

1. every design path is simulated on the fine mesh by the full
   :class:`~idbench_fem.models.solid.SolidModel` (``idbench.fine_path``:
   cached by content like a truth, so a calibration on the same paths, or
   another reduction of the same design, reuses them);
2. the states of every step are the snapshots; their POD
   (:mod:`idbench_fem.fem.pod`) gives the basis V (n x r);
3. ECSW (:mod:`idbench_fem.fem.ecsw`) samples and weighs the elements on the
   projected snapshots V V^T u_s (at most :data:`TRAINING` of them), per
   parameter region.

The result, :class:`Reduction`, is cached on disk (``reduction-KEY.npz`` in
idbench's cache folder, keyed on the fine models' descriptions, the design's
moduli and steps, the spec and :data:`REDUCTION_VERSION`), with what it cost:
the fine paths, their steps and the seconds spent simulating them, and the
offline total. The online half is :mod:`idbench_fem.models.reduced`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

import idbench
from idbench import ConfigError
from idbench_fem.bodies.catalog import get_mesh, mesh_file
from idbench_fem.bodies.description import Body
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.fem.ecsw import ecsw
from idbench_fem.fem.element_set import ElementSet
from idbench_fem.fem.hyper import Springs
from idbench_fem.fem.pod import modes_for, pod, projection_error
from idbench_fem.fem.svk_assembly import shape_gradients
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid_settings import SolidSettings

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

PREFIX = "rom:"
"""How a mesh spec asks for a reduced model."""

REDUCTION_VERSION = "reduction/2"
"""Changes when a reduction's result changes (keys the reduction cache)."""

POD_TOLERANCE = 1e-7
"""Default share of the snapshots' energy the modes may leave out."""

ECSW_TOLERANCE = 1e-3
"""Default relative fit of ECSW's weighted reduced forces to the exact ones."""

TRAINING = 40
"""At most this many projected snapshots train ECSW (evenly over the design)."""

SYNTAX = (
    "rom:MESH[:MODES[:SAMPLING]]: a reduced model of the body's mesh MESH (a mesh "
    "spec: truth, a node count, a file), with MODES POD modes (a whole number) or "
    f"the modes that leave out at most that share of the snapshots' energy (a "
    f"number < 1; default {POD_TOLERANCE:g}), and SAMPLING the ECSW fit (a number "
    f"< 1; default {ECSW_TOLERANCE:g}), a cap on the sampled elements per region (a "
    "whole number) or 'all' (every element, weight 1); its snapshots come from "
    "the body's [design]"
)
"""The spec's syntax, for messages and ``--help``."""


@dataclass(frozen=True)
class ReductionSpec:
    """A parsed ``rom:`` mesh spec (see :data:`SYNTAX`).

    Attributes
    ----------
    mesh
        The fine mesh spec.
    modes
        Number of POD modes, or None (then ``pod_tolerance`` decides).
    pod_tolerance
        Share of the snapshots' energy the modes may leave out.
    ecsw_tolerance
        ECSW's relative fit; 0: every element with weight 1.
    max_elements
        Cap on the sampled elements per region (None: none).
    """

    mesh: str
    modes: int | None = None
    pod_tolerance: float = POD_TOLERANCE
    ecsw_tolerance: float = ECSW_TOLERANCE
    max_elements: int | None = None


def is_reduced(spec: str) -> bool:
    """Whether a mesh spec asks for a reduced model (``rom:...``)."""
    return str(spec).strip().startswith(PREFIX)


def parse_spec(spec: str) -> ReductionSpec:
    """Parse ``rom:MESH[:MODES[:SAMPLING]]`` (see :data:`SYNTAX`).

    Raises
    ------
    ConfigError
        One line naming the bad part and the syntax.
    """
    parts = str(spec).strip()[len(PREFIX):].split(":")
    if not parts[0] or len(parts) > 3:
        raise ConfigError(f"mesh {spec!r}: need {SYNTAX}")
    out: dict[str, Any] = {"mesh": parts[0]}
    try:
        if len(parts) > 1 and parts[1]:
            value = float(parts[1])
            if parts[1].isdigit() and int(parts[1]) >= 1:
                out["modes"] = int(parts[1])
            elif 0 < value < 1:
                out["pod_tolerance"] = value
            else:
                raise ValueError(parts[1])
        if len(parts) > 2 and parts[2]:
            if parts[2] == "all":
                out["ecsw_tolerance"] = 0.0
            elif parts[2].isdigit() and int(parts[2]) >= 1:
                out["max_elements"] = int(parts[2])
            elif 0 < float(parts[2]) < 1:
                out["ecsw_tolerance"] = float(parts[2])
            else:
                raise ValueError(parts[2])
    except ValueError as exc:
        bad = f"mesh {spec!r}: bad part {str(exc)!r}"
        raise ConfigError(f"{bad}; need {SYNTAX}") from None
    return ReductionSpec(**out)


@dataclass(frozen=True)
class Reduction:
    """A reduction of a fine mesh: basis, sampled elements, weights, cost.

    Attributes
    ----------
    key
        Its cache key.
    basis
        V (n, r), orthonormal columns on the fine mesh's free dofs.
    singular
        The POD singular values (all, not only the r kept).
    elements, weights
        The sampled elements (indices into the fine mesh's tets) and weights.
    info
        Scalars: ``fine_paths``, ``fine_steps``, ``design_seconds`` (simulating
        the paths that were not cached yet), ``offline_seconds``,
        ``projection_error`` (largest relative projection error of a
        snapshot), ``ecsw_fit``, ``snapshots``.
    """

    key: str
    basis: FloatArray
    singular: FloatArray
    elements: IntArray
    weights: FloatArray
    info: dict[str, float]

    @property
    def modes(self) -> int:
        """The number of modes r."""
        return int(self.basis.shape[1])

    def arrays(self) -> dict[str, Any]:
        """What the cache stores."""
        names = sorted(self.info)
        return {
            "basis": self.basis, "singular": self.singular,
            "elements": self.elements, "weights": self.weights,
            "info_names": np.array(names),
            "info_values": np.array([self.info[n] for n in names], dtype=float),
        }  # fmt: skip

    @classmethod
    def of(cls, key: str, arrays: dict[str, Any]) -> Reduction:
        """From the cache's arrays."""
        info = dict(
            zip(
                [str(n) for n in arrays["info_names"]],
                [float(v) for v in arrays["info_values"]],
                strict=True,
            )
        )
        return cls(key, np.asarray(arrays["basis"], float),
                   np.asarray(arrays["singular"], float),
                   np.asarray(arrays["elements"], np.int64),
                   np.asarray(arrays["weights"], float), info)  # fmt: skip


def free_numbering(n_nodes: int, fixed: IntArray) -> IntArray:
    """Full dof index -> free dof index (or -1), as the assemblers number them."""
    free = np.ones(n_nodes, dtype=bool)
    free[np.asarray(fixed, dtype=np.int64)] = False
    node_dof = np.full(n_nodes, -1, dtype=np.int64)
    node_dof[free] = 3 * np.arange(int(free.sum()))
    out = (node_dof[:, None] + np.arange(3)).ravel()
    out[np.repeat(~free, 3)] = -1
    return out


def element_dofs(model: SolidModel, tets: IntArray | None = None) -> IntArray:
    """Free-dof indices (T, 12) of the model's tets (or of ``tets``), -1 if fixed."""
    points, all_tets = model.mesh()
    tets = all_tets if tets is None else tets
    f2f = free_numbering(len(points), model.fixed_nodes)
    return np.asarray(f2f[(3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)])


def element_factors(model: SolidModel) -> FloatArray:
    """c_e (T,): each element's modulus over its region's parameter."""
    true = np.asarray(model.parameters.default, dtype=float)
    regions = model.element_regions
    moduli = model.element_moduli(true, None)[: len(regions)]  # (springs' after)
    return np.asarray(moduli / true[regions])


def moduli_count(model: SolidModel) -> int:
    """The parameters that are moduli of element regions (the springs' follow)."""
    springs = model.springs
    return model.parameters.p - (0 if springs is None else len(springs.names))


def reduced_springs(model: SolidModel, basis: FloatArray) -> Springs | None:
    """The model's spring channels projected on ``basis`` (None: no springs)."""
    springs = model.springs
    if springs is None:
        return None
    return Springs.project(springs.matrices, springs.index, springs.known, basis)


def element_set(model: SolidModel, tets: IntArray) -> ElementSet:
    """The kernels of the model's law on ``tets``."""
    points, _ = model.mesh()
    grads, volumes = shape_gradients(points, tets)
    return ElementSet(grads, volumes, model.law_name, model.nu)


def design_models(
    body: Body, spec: ReductionSpec, settings: SolidSettings,
    fine: SolidMesh | None = None,
) -> list[SolidModel]:  # fmt: skip
    """The fine model of each design manipulation (its steps, the design's).

    Markers and grid are placed on the fine mesh itself (the states do not
    depend on them; the cache keys of the paths do).

    Raises
    ------
    ConfigError
        The body has no ``[design]``.
    """
    design = body.design
    if design is None:
        raise ConfigError(
            f"{body.source}: a reduced model needs the body's offline design: add "
            "a [design] table (manipulations, moduli, steps; see the body TOML "
            "reference)"
        )
    dbody = design.body(body)
    if fine is None:  # (a body built in memory gives its mesh)
        fine = get_mesh(mesh_file(body, spec.mesh))
    # markers placed on the fine mesh itself, whatever the comparison's
    # reference: the states do not depend on them, so every comparison
    # shares the paths' cache entries (a truth on that mesh too)
    reference = fine
    return [
        SolidModel(dbody, fine, name, reference, design.steps, 1, settings)
        for name in design.manipulations
    ]


def reduction_key(body: Body, spec: ReductionSpec, models: list[SolidModel]) -> str:
    """The cache key of a reduction (see the module)."""
    assert body.design is not None
    descs = [
        {k: v for k, v in m.describe().items() if k not in ("markers", "grid_points")}
        for m in models
    ]
    return idbench.stable_hash(
        {"fine": descs, "design": body.design.describe(), "spec": spec.__dict__,
         "version": REDUCTION_VERSION, "idbench": idbench.__version__},
        length=24,
    )  # fmt: skip


Check = Callable[["Reduction", list[SolidModel], list[FloatArray]], dict[str, float]]
"""Scores a reduction on its design's paths (their fine models and states)."""


def reduce(
    body: Body, spec: ReductionSpec, settings: SolidSettings,
    check_design: Check | None = None, fine: SolidMesh | None = None,
) -> Reduction:  # fmt: skip
    """The reduction of ``spec`` for ``body``: from the cache, or built (see module).

    ``check_design`` adds its scores to a reduction's ``info`` before it is
    cached (:func:`idbench_fem.models.reduced.design_check`).
    """
    models = design_models(body, spec, settings, fine)
    key = reduction_key(body, spec, models)
    path = idbench.cache_dir() / f"reduction-{key}.npz"

    def check(arrays: dict[str, Any]) -> None:
        if arrays["basis"].shape[0] != models[0].n_state:
            raise ValueError("basis of another mesh")
        if not np.all(np.isfinite(arrays["basis"])):
            raise ValueError("non-finite basis")

    cached = idbench.read_entry(path, key, check, "reduction")
    if cached is not None:
        return Reduction.of(key, cached)
    out = build(body, spec, models, key, check_design)
    idbench.write_entry(path, key, out.arrays(), "reduction")
    return out


def design_snapshots(
    body: Body, models: list[SolidModel]
) -> tuple[list[FloatArray], dict[str, float]]:
    """Each design path's states (K_i, n), simulated or from the cache; the cost.

    Paths in the order of ``models`` and, for each, of the design's moduli.
    """
    assert body.design is not None
    thetas = body.design.thetas()
    total = len(models) * len(thetas)
    states, steps, seconds, done = [], 0, 0.0, 0
    for model in models:
        for theta in thetas:
            done += 1
            t0 = time.perf_counter()
            path = idbench.fine_path(model, theta)
            dt = time.perf_counter() - t0
            seconds += dt
            steps += len(path)
            states.append(path)
            log.info("design path %d/%d: %s at %s, %d/%d steps, %.1f s", done,
                     total, model.manipulation.name, np.round(theta, 1).tolist(),
                     len(path), model.n_steps, dt)  # fmt: skip
    info = {"fine_paths": float(total), "fine_steps": float(steps),
            "design_seconds": seconds}  # fmt: skip
    return states, info


def build(
    body: Body, spec: ReductionSpec, models: list[SolidModel], key: str,
    check_design: Check | None = None,
) -> Reduction:  # fmt: skip
    """POD and ECSW over the design's snapshots (the cache's miss path)."""
    t0 = time.perf_counter()
    paths, info = design_snapshots(body, models)
    snapshots = np.vstack(paths)
    modes, singular = pod(snapshots)
    r = spec.modes or modes_for(singular, spec.pod_tolerance)
    if r > modes.shape[1]:
        raise ConfigError(
            f"rom:{spec.mesh}:{r}: the design's snapshots give {modes.shape[1]} "
            "modes at most; ask for fewer or add design paths"
        )
    V = modes[:, :r]
    model = models[0]
    _, tets = model.mesh()
    if spec.ecsw_tolerance == 0.0:
        elements = np.arange(len(tets), dtype=np.int64)
        weights = np.ones(len(tets))
        fit = 0.0
    else:
        every = max(1, int(np.ceil(len(snapshots) / TRAINING)))
        training = snapshots[::every] @ V
        sampled = ecsw(
            element_set(model, tets), element_dofs(model), V, element_factors(model),
            model.element_regions, moduli_count(model), training,
            spec.ecsw_tolerance, spec.max_elements,
        )  # fmt: skip
        elements, weights, fit = sampled.elements, sampled.weights, sampled.residual
    info.update(
        snapshots=float(len(snapshots)),
        projection_error=projection_error(V, snapshots),
        ecsw_fit=fit,
        offline_seconds=time.perf_counter() - t0,
    )
    out = Reduction(key, V, singular, elements, weights, info)
    if check_design is not None:
        info.update(check_design(out, models, paths))
        info["offline_seconds"] = time.perf_counter() - t0
    log.info("reduction %s: %d modes, %d of %d elements, %.0f s offline", key, r,
             len(elements), len(tets), info["offline_seconds"])  # fmt: skip
    return out
