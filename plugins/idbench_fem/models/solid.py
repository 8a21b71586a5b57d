r"""The ``solid`` model: any tetrahedral body described by a body TOML.

The one forward model of the plugin: ``svk-beam`` is this model on a body
built in memory (:mod:`idbench_fem.models.beam`).

:class:`SolidModel` solves each quasi-static load step of a manipulation by
Newton's method on the free displacements of a P1 tet mesh: the body's fixed
region has all components zero, the manipulation's dead load is ramped as
:math:`f_{ext}(k) = (k/K) f_{ext}(1)`, the law is the body's (``svk`` or
``neo-hookean``) and the moduli are

.. math::

    E_e = \theta_{r(e)}\, c_e,

with :math:`r(e)` the element's parameter region (one region: ``E``) and
:math:`c_e` the element's true modulus over its region's true value (1 except
where ``[material] E_regions`` makes a region stiffer than the parameter it
belongs to). The internal force is linear in theta,
:math:`f_{int}(u) = \sum_r \theta_r g_r(u)`, so at equilibrium
:math:`\partial u / \partial \theta_r = -K^{-1} g_r(u)`: one back-substitution
per parameter with the last factorization.

A displacement-controlled grasp (``displacement`` instead of ``force``)
prescribes every component of its patch's nodes, ramped as
:math:`u_p(k) = (k/K) d`: the state keeps those dofs (set to u_p(k) by each
step, so markers and shape errors see them) but Newton solves only for the
others, through :class:`~idbench_fem.fem.prescribed.PrescribedAssembler`;
f_ext is zero, and Newton's floor is rtol times the load the first step
puts on the unknowns. :meth:`reaction` is then the tool's force, and the
model declares ``needs_observed = ("reaction",)``: its displacements do not
depend on a homogeneous E. Under a load (any other manipulation) the
reaction is the support's, which balances the load whatever E: the model
declares ``inputs = ("reaction",)`` (:class:`idbench.InputsModel`).

Newton (:mod:`idbench_fem.fem.newton`): converged
when :math:`\|r\| \le \max(\mathrm{rtol} \|f_{ext}(k)\|, \mathrm{atol})`
with rtol = 1e-8 and atol = 1e-12 times the end force; each update is halved
(up to 8 times) while an element would have det F <= 0.

Sigma points of a filter step go through :meth:`SolidModel.step_many`
(:mod:`idbench_fem.fem.batched`): one pair solved by Newton, the
others predicted from its sensitivity and corrected by chord steps on its
scaled factorization (both laws are linear in the moduli), optionally shared
with helper processes (setting ``processes``).

Markers, shape-error points, probes and targets are placed on the reference
mesh (the comparison's truth) and located in each model mesh by
:mod:`idbench_fem.models.points`. A manipulation with ``conserve =
"resultant"`` scales this mesh's nodal loads by :attr:`load_factor`, so that
their resultant is the reference mesh's; :meth:`load_figures` measures the
load either way (:mod:`idbench_fem.bodies.figures`).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from idbench import ConfigError, ModelSpec, Scenario
from idbench_fem.bodies import resolve
from idbench_fem.bodies.catalog import body_path, get_body, get_mesh, mesh_file
from idbench_fem.bodies.description import Body
from idbench_fem.bodies.figures import conserve_scale, figures
from idbench_fem.bodies.loads import nodal_forces, traction_weights
from idbench_fem.bodies.mesh import SolidMesh, extent
from idbench_fem.bodies.regions import region_facets
from idbench_fem.fem.batched import BatchedSteps
from idbench_fem.fem.law_assembly import LawAssembler
from idbench_fem.fem.newton import (
    ASSEMBLY_BUFFERS,
    CHORD_RATIO,
    checked_state,
    freeze,
)
from idbench_fem.fem.solver import resolve_backend
from idbench_fem.fem.svk_assembly import Assembler
from idbench_fem.models.digests import body_digest, mesh_digest
from idbench_fem.models.driven import DrivenGrasp
from idbench_fem.models.field_members import FieldMembers
from idbench_fem.models.observables import LinearReadouts, Observables
from idbench_fem.models.parameterisation import parameterise
from idbench_fem.models.points import place_points, reference_markers
from idbench_fem.models.rest_shape import rest_mesh
from idbench_fem.models.solid_settings import DEFAULT_BODY, SolidSettings
from idbench_fem.models.supported import Supported

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

MODEL_VERSION = "solid/3"
"""Changes when a solution changes beyond round-off (the truth cache keys on it);
2: chord steps in Newton (same tolerance); 3: a step continuing the previous
one reuses its factorization, from a secant prediction (same tolerance)."""

RTOL = 1e-8
ATOL = 1e-12
MAX_ITERATIONS = 25


class SolidModel(
    DrivenGrasp, Supported, LinearReadouts, Observables, FieldMembers, BatchedSteps
):
    """A body under one manipulation, on one mesh, stepped by Newton.

    Parameters
    ----------
    body
        The parsed body description.
    mesh
        The model mesh.
    manipulation
        Name of the body's manipulation (the scenario).
    reference
        The mesh markers and shape-error points are placed on.
    n_steps, markers
        Load steps K and number of markers M.
    settings
        Overrides and solver options.
    absolute_atol
        Newton's absolute floor in N (None: ``settings.atol`` or 1e-12 times
        the end force).

    Attributes
    ----------
    marker_points, target_points
        The markers' (M, 3) and the targets' (T, 3) undeformed positions, in
        the order of :meth:`observe` and :meth:`targets`
        (:class:`idbench.PlacedPointsModel`: where a report draws them).
    """

    def __init__(
        self,
        body: Body,
        mesh: SolidMesh,
        manipulation: str,
        reference: SolidMesh,
        n_steps: int = 20,
        markers: int = 2,
        settings: SolidSettings | None = None,
        *,
        absolute_atol: float | None = None,
    ) -> None:
        if n_steps < 1:
            raise ValueError(f"n_steps = {n_steps}: need at least one load step")
        s = settings or SolidSettings()
        self.body, self.mesh_data, self.settings = body, mesh, s
        self.manipulation = body.manipulation(manipulation)
        self.n_steps = int(n_steps)
        self.rtol = float(s.rtol or RTOL)
        self.max_iterations = int(s.max_iterations or MAX_ITERATIONS)
        self.sensitivity_refine = s.sensitivity_refine is not False
        chord = s.chord_ratio
        self.chord_ratio = float(CHORD_RATIO if chord is None else chord)
        if not 0.0 <= self.chord_ratio < 1.0:
            raise ValueError(
                f"chord_ratio {self.chord_ratio!r}: must be in [0, 1) (0: plain Newton)"
            )
        self.backend = resolve_backend(s.solver)
        self.law_name = s.law or body.material.law
        self.force_is_cubic = self.law_name == "svk"
        self._init_batched(
            s.processes or 1,
            functools.partial(
                SolidModel, body, mesh, manipulation, reference, n_steps, markers,
                replace(s, processes=None), absolute_atol=absolute_atol,
            ),
        )  # fmt: skip
        self.nu = float(body.material.nu if s.nu is None else s.nu)

        fixed = resolve.fixed_nodes(body, mesh)
        free = np.ones(len(mesh.points), dtype=bool)
        free[fixed] = False
        self.n_nodes = len(mesh.points)
        self.bounds, self.volume = extent(mesh.points, mesh.tets)
        from idbench_fem.fem.materials import Material, make_material

        law = cast(Material, make_material(self.law_name, 1.0, self.nu))
        if self.law_name == "svk" and s.kernel == "auto":
            self._asm: Any = Assembler(mesh.points, mesh.tets, free, self.nu)
        else:
            self._asm = LawAssembler(mesh.points, mesh.tets, free, law)
        self.n_state = int(self._asm.n_free)
        self._driven: IntArray | None = None
        if self.manipulation.driven:  # the state keeps them, Newton does not
            self._init_driven(body, mesh, float(s.load_scale))
        else:  # a load: the support's reaction balances it, whatever E
            self.inputs = ("reaction",)

        # parameters: E, E per region or per field cell (E_e = theta_r(e) c_e)
        params = parameterise(body, mesh, reference, s)
        self.element_regions, self._factors = params.regions, params.factors
        self.parameters, self.parameter_field = params.spec, params.field
        self._described = params.describe or {}
        self._attach_springs(body, mesh)  # [[support]]: springs, their parameters

        f1 = nodal_forces(
            self.manipulation, mesh, body.material.density, t=float(s.load_scale)
        )
        # conserve = "resultant": the reference mesh's total force (else 1.0)
        self.load_factor = conserve_scale(body, self.manipulation, mesh, reference)
        if self.load_factor != 1.0:
            f1 = self.load_factor * f1
        self._figures = figures(
            body, self.manipulation, mesh, f1, fixed, self.load_factor
        )
        self._f_end = f1.ravel()[self._state_asm().free_dofs]
        if self._driven is not None:  # zeros: no load but the tool's
            self._f_end = self._f_end[self._asm.unknown]
        self._load_weights: FloatArray | None = None
        if self.manipulation.kind == "traction":  # f(k) = w (k/K) t, per component
            assert self.manipulation.region is not None
            facets = region_facets(mesh, self.manipulation.region)
            weights = traction_weights(mesh, facets)
            self._load_weights = np.repeat(weights, 3)[self._asm.free_dofs]
            self._load_component = np.tile(np.arange(3), self.n_nodes)[
                self._asm.free_dofs
            ]
            self._traction = float(s.load_scale) * np.asarray(self.manipulation.vector)
            if self.load_factor != 1.0:
                self._traction = self.load_factor * self._traction
        end = float(np.linalg.norm(self.external_force(self.n_steps)))
        self.atol = (
            float(s.atol or ATOL) * end
            if absolute_atol is None
            else float(absolute_atol)
        )
        if self._driven is not None and absolute_atol is None:
            # no f_ext: the floor is the tolerance (rtol, or settings.atol, of
            # the load the grasp's first step puts on the unknowns
            self.atol = float(s.atol or self.rtol) * self._driven_force_scale()

        # the candidate markers: the body's listed points, or its region's nodes
        self.max_markers = len(reference_markers(body, reference))
        placed = place_points(
            body, mesh, reference, markers, self._state_asm().full_to_free
        )
        self.marker_points = placed.marker_points
        self.grid_points = placed.grid_points
        self.target_points = placed.target_points
        self._obs, self._grid = placed.markers, placed.grid
        self._probes, self._targets = placed.probes, placed.targets
        self._reference = reference
        self._cost = [0, 0, 0]
        self.last_residuals: list[float] = []
        freeze(self)  # shared by the copies runs get (see NewtonSolve.__copy__)
        freeze(self._asm, keep=ASSEMBLY_BUFFERS)
        if self._driven is not None:
            freeze(self._asm.inner, keep=ASSEMBLY_BUFFERS)

    # -- the ForwardModel protocol -------------------------------------------

    def reset(self) -> FloatArray:
        """Return the unloaded state: zeros, shape (n_state,)."""
        return np.zeros(self.n_state)

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """Solve load step ``k`` (1..K) with ``theta`` from ``state``.

        Raises
        ------
        ModelFailure
            No convergence, a non-finite residual, or inverted elements that
            backtracking cannot avoid.
        """
        modulus = self.element_moduli(theta, k)
        u = checked_state(state, k, substeps, self.n_steps, self.n_state)
        self._cost[0] += 1
        self._factored_key = None
        if self._driven is not None:
            return self._driven_step(theta, k, u, modulus, substeps)
        if substeps == 1 and self.settings.path_reuse is not False:
            # along a path: reuses the last step's factorization
            u = self._path_step(theta, k, u, modulus)
            self._remember_factorization(theta, u)
            return u
        self._last_path_step = None
        for j in range(1, substeps + 1):
            u, _ = self._newton(modulus, self._load(k, j / substeps), u, k)
        self._remember_factorization(theta, u)
        return u

    def step_many(self, thetas: FloatArray, k: int, states: FloatArray) -> FloatArray:
        """Solve load step ``k`` for r parameter/state pairs, sharing factorizations.

        ``thetas`` (r, p), ``states`` (r, n) -> states (r, n); row i equals
        ``step(thetas[i], k, states[i])`` to the Newton tolerance (see
        :mod:`idbench_fem.fem.batched`; a displacement-controlled grasp's
        prescribed dofs are set to step k's values).

        Raises
        ------
        ModelFailure
            If any pair fails (the caller may retry pairs with ``step``).
        """
        if self._driven is None:
            return super().step_many(thetas, k, states)
        X = np.asarray(states, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.n_state:
            raise ValueError(
                f"states has shape {X.shape}, expected (r, {self.n_state})"
            )
        if not 1 <= k <= self.n_steps:
            raise ValueError(f"load step k = {k}: must be in 1..{self.n_steps}")
        self.prescribe(k)
        out = super().step_many(thetas, k, X[:, self._asm.unknown])
        return np.asarray(self._asm.embed(out))

    def probes(self, state: FloatArray) -> dict[str, float]:
        """The body's probes ``NAME_x``, ``NAME_y``, ``NAME_z`` (m); else ``u_max``.

        ``u_max`` is the largest nodal displacement component (m), given for a
        body without ``[[probe]]`` points.
        """
        if not self._probes:
            return {"u_max": float(np.abs(state).max(initial=0.0))}
        out = {}
        for name, matrix in self._probes.items():
            u = matrix @ state
            out.update({f"{name}_x": u[0], f"{name}_y": u[1], f"{name}_z": u[2]})
        return out

    def probe(self, name: str, state: FloatArray) -> FloatArray:
        """Displacement (3,) of the body's probe point ``name``."""
        if name not in self._probes:
            raise ValueError(
                f"probe {name!r}: the body has {', '.join(self._probes) or 'none'}"
            )
        return np.asarray(self._probes[name] @ state)

    def sensitivity(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """D observe / d theta at the converged ``state``, shape (3M, p).

        du/dtheta_r = -K(u)^-1 g_r(u), by :meth:`_state_sensitivity`: the
        factorization of the step just solved plus one step of iterative
        refinement if it ended with a Newton update, else K(u) factored.
        """
        modulus = self.element_moduli(theta, k)
        u = np.asarray(state, dtype=np.float64)
        if self._driven is not None:  # on the unknowns; the tool's dofs do not move
            self._asm.values = u[self._asm.prescribed]
            u = u[self._asm.unknown]
        kin = self._asm.kinematics(u, self._factors)
        g = self._asm.region_forces(kin, self.element_regions, self.parameters.p)
        du = self._state_sensitivity(theta, k, u, modulus, g, self.sensitivity_refine)
        if self._driven is not None:
            full = np.zeros((self.n_state, du.reshape(len(u), -1).shape[1]))
            full[self._asm.unknown] = du.reshape(len(u), -1)
            du = full
        return np.asarray(self._obs @ du.reshape(self.n_state, -1))

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable description of everything the results depend on."""
        m = self.manipulation
        out = {
            "model": "solid",
            "code_version": MODEL_VERSION,
            "body": Path(self.body.source).name,  # names, not paths: the
            "body_sha256": body_digest(self.body),  # contents key it
            "mesh": Path(self.mesh_data.path).name,
            "mesh_sha256": mesh_digest(self.mesh_data),
            "reference_sha256": mesh_digest(self._reference),
            "n_nodes": self.n_nodes,
            "n_elements": len(self.mesh_data.tets),
            "law": self.law_name,
            "nu": self.nu,
            "load_scale": self.settings.load_scale,
            "parameter_names": list(self.parameters.names),
            "scenario": {"name": m.name, "kind": m.kind},
            "markers": len(self.marker_points),
            "grid_points": len(self.grid_points),
            "n_steps": self.n_steps,
            "rtol": self.rtol,
            "atol": self.atol,
            "max_iterations": self.max_iterations,
        }
        for name in ("chord_ratio", "sensitivity_refine", "path_reuse"):
            if getattr(self.settings, name) is not None:
                out[name] = getattr(self.settings, name)
        if m.displacement is not None:
            out["scenario"]["displacement"] = list(m.displacement)
        if m.conserve != "none":
            out["scenario"]["conserve"] = m.conserve
        return {**out, **self._described}

    def load_figures(self) -> dict[str, float]:
        """The end load on this mesh, measured (:mod:`idbench_fem.bodies.figures`).

        ``resultant`` (N), ``moment`` (N m, about the fixed region's
        centroid), ``area`` (the loaded area, m^2), ``fixed_area`` (m^2),
        ``volume`` (m^3), ``mass`` (kg); after ``conserve``'s scaling.
        """
        return dict(self._figures)

    # -- extras: idbench simulate, tests ------------------------------------------

    def mesh(self) -> tuple[FloatArray, IntArray]:
        """Node coordinates (N, 3) and tets (T, 4)."""
        return self.mesh_data.points, self.mesh_data.tets

    def cell_data(self) -> dict[str, FloatArray]:
        """Per-tet tags for ParaView: parameter ``region`` and ``E_factor`` c_e."""
        return {"region": self.element_regions.astype(float), "E_factor": self._factors}

    def displacement_field(self, state: FloatArray) -> FloatArray:
        """Displacement of every node (N, 3), zeros on the fixed ones."""
        full = np.zeros(3 * self.n_nodes)
        full[self._state_asm().free_dofs] = state
        return full.reshape(-1, 3)

    def external_force(self, k: int) -> FloatArray:
        """External force on the free dofs at step ``k``, (n_state,)."""
        if self._load_weights is None:
            return (k / self.n_steps) * self._f_end
        return self._spread((k / self.n_steps) * self._traction)

    def internal_force(self, theta: FloatArray, state: FloatArray) -> FloatArray:
        """Internal force f_int(state; theta) on the free dofs, (n_state,).

        The state's dofs: with a displacement-controlled grasp its prescribed
        ones too (where the tool's force is).
        """
        modulus = self.element_moduli(theta, None)
        u = np.asarray(state, dtype=np.float64)
        asm = self._state_asm()
        return np.asarray(asm.forces(asm.kinematics(u, modulus)))

    def residual(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """Newton residual f_int(state; theta) - f_ext(k), shape (n_state,).

        With a displacement-controlled grasp, on the unknowns only (the
        state's prescribed dofs as they are), shape (n_unknowns,).
        """
        if self._driven is None:
            return self.internal_force(theta, state) - self.external_force(k)
        f = self.internal_force(theta, state)[self._asm.unknown]
        return np.asarray(f - self.external_force(k))

    def tangent(self, theta: FloatArray, state: FloatArray) -> Any:
        """The free-free tangent at ``state`` (scipy CSR; of the unknowns if driven)."""
        modulus = self.element_moduli(theta, None)
        u = np.asarray(state, dtype=np.float64)
        if self._driven is not None:
            self._asm.values = u[self._asm.prescribed]
            u = u[self._asm.unknown]
        kin = self._asm.kinematics(u, modulus)
        return self._pattern.matrix(self._asm.tangent_data(kin, modulus, self._pattern))

    @property
    def fixed_nodes(self) -> IntArray:
        """Indices of the fixed nodes (all displacement components zero)."""
        f2f = self._state_asm().full_to_free
        return np.flatnonzero(f2f.reshape(-1, 3)[:, 0] < 0)

    # -- internals -------------------------------------------------------------

    def _load(self, k: int, fraction: float) -> FloatArray:
        """The load ``fraction`` of the way from step k - 1's to step k's."""
        if self._load_weights is None:
            return ((k - 1 + fraction) / self.n_steps) * self._f_end
        t0 = ((k - 1) / self.n_steps) * self._traction
        t1 = (k / self.n_steps) * self._traction
        return self._spread(t0 + fraction * (t1 - t0))

    def _spread(self, traction: FloatArray) -> FloatArray:
        """Nodal forces on the free dofs of a uniform traction vector (3,)."""
        assert self._load_weights is not None
        return np.asarray(self._load_weights * traction[self._load_component])

    def element_moduli(self, theta: FloatArray, k: int | None) -> FloatArray:
        """Moduli theta_{r(e)} c_e (T,), then any springs' (T + q,); theta checked."""
        th = self._theta(theta, k)
        out = np.asarray(th[self.element_regions] * self._factors)
        return out if self._springs is None else self._springs.moduli(out, th)


def make_model(spec: ModelSpec) -> SolidModel:
    """Build the model of ``spec`` (registered as ``"solid"``).

    ``spec.scenario.load`` names the manipulation (``{"manipulation": NAME}``,
    optionally ``"body"``: else the settings' body; a settings' body other
    than the default must be that body); ``spec.mesh`` is a mesh spec of that
    body (:mod:`idbench_fem.bodies.catalog`).

    Raises
    ------
    ValueError
        One line: unknown body, manipulation or mesh, or a body that does not
        fit the mesh (:mod:`idbench_fem.bodies.resolve`).
    """
    settings = spec.settings
    if settings is None:
        settings = SolidSettings()
    elif isinstance(settings, Mapping):
        settings = SolidSettings(**settings)
    load = spec.scenario.load
    name = load.get("manipulation") if isinstance(load, dict) else None
    if not isinstance(name, str):
        raise ValueError(
            f"scenario {spec.scenario.name!r}: the solid model needs a load "
            f"{{'manipulation': NAME[, 'body': FILE]}}, got {load!r}"
        )
    named = str(load.get("body", settings.body))
    body = get_body(named)
    if settings.body != DEFAULT_BODY and body_path(named) != body_path(settings.body):
        own = get_body(settings.body)
        raise ConfigError(
            f"scenario {spec.scenario.name!r} is a manipulation of body {named!r}, "
            f"not of the model's body {settings.body!r} (its manipulations: "
            f"{', '.join(m.name for m in own.manipulations)})"
        )
    body.manipulation(name)  # one line if unknown
    if str(spec.mesh).startswith("rom:"):  # a reduced model of a fine mesh
        from idbench_fem.models.reduced import reduced_model

        return reduced_model(body, name, spec, settings)  # type: ignore[return-value]
    mesh = rest_mesh(body, get_mesh(mesh_file(body, spec.mesh)), settings)
    on = get_mesh(mesh_file(body, settings.reference or "truth"))
    reference = rest_mesh(body, on, settings)  # [reference]: stress-free shapes
    return SolidModel(body, mesh, name, reference, spec.n_steps, spec.markers, settings)


def scenario_of(body_spec: str, manipulation: str) -> Scenario:
    """An ad-hoc scenario for a body's manipulation (scripts, tests)."""
    return Scenario(manipulation, {"body": body_spec, "manipulation": manipulation})
