"""The St Venant-Kirchhoff cantilever beam as an idbench forward model.

:class:`SvkBeam` solves each quasi-static load step by Newton's method, warm
started from the state passed in, on the free displacements of a P1 tet mesh
clamped at x = min x and loaded by a dead uniform traction on x = max x.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench import Cost, ModelSpec, ParameterSpec, Scenario
from idbench_fem.bodies import box as meshes
from idbench_fem.bodies.mesh import extent
from idbench_fem.bodies.regions import parameter_regions
from idbench_fem.fem.batched import BatchedSteps
from idbench_fem.fem.interpolation import (
    grid_points,
    interpolation_matrix,
    marker_points,
)
from idbench_fem.fem.newton import ASSEMBLY_BUFFERS, CHORD_RATIO, freeze
from idbench_fem.fem.solver import resolve_backend
from idbench_fem.fem.svk_assembly import Assembler
from idbench_fem.models.beam_settings import BeamSettings, EndTraction
from idbench_fem.models.observables import Observables

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

MODEL_VERSION = "svk-beam/2"
"""Changes when a solution changes beyond round-off (the truth cache keys on it);
2: chord steps in Newton (same tolerance, solutions differ by about 1e-10)."""

RTOL = 1e-8
"""Newton tolerance on ||residual|| relative to ||external force|| of the step."""

ATOL = 1e-12
"""Absolute floor, relative to ||external force|| at the end of the load path."""

MAX_ITERATIONS = 25


class SvkBeam(Observables, BatchedSteps):
    """P1 St Venant-Kirchhoff cantilever under an end traction, stepped by Newton.

    Parameters
    ----------
    beam
        The mesh and its boundary.
    scenario
        The load path, read as an end traction (:class:`EndTraction`).
    n_steps
        Number of load steps K.
    nu
        Poisson's ratio.
    markers
        Number of marker points (see
        :func:`idbench_fem.fem.interpolation.marker_points`).
    grid
        Shape-error grid point counts (nx, ny, nz).
    parameters
        ``"E"`` or ``"E_regions"`` (see :mod:`idbench_fem.bodies.regions`).
    options
        ``regions``, ``inclusion``, ``rtol``, ``atol``, ``max_iterations``,
        ``sensitivity_refine``, ``chord_ratio`` (see
        :data:`idbench_fem.fem.newton.CHORD_RATIO`; 0: plain Newton), ``solver``
        (``"pardiso"``/``"scipy"``; default
        from ``IDBENCH_SOLVER``), ``processes`` (default 1; n > 1: n - 1
        helper processes share the pairs of :meth:`step_many`, see
        :mod:`idbench_fem.fem.step_workers`).

    Attributes
    ----------
    last_residuals
        Residual norms of the Newton iterations of the last (sub-)step solved.
    """

    force_is_cubic = True  # SVK: P = F S is cubic in the displacements

    def __init__(
        self,
        beam: meshes.BeamMesh,
        scenario: Scenario | EndTraction,
        n_steps: int = 20,
        nu: float = 0.45,
        markers: int = 2,
        grid: tuple[int, int, int] = (20, 4, 4),
        parameters: str = "E",
        options: dict[str, Any] | None = None,
    ) -> None:
        if n_steps < 1:
            raise ValueError(f"n_steps = {n_steps}: need at least one load step")
        opts = dict(options or {})
        self.beam = beam
        self.scenario = EndTraction.of(scenario)
        self.n_steps = int(n_steps)
        self.nu = float(nu)
        self.options = opts
        self.rtol = float(opts.get("rtol", RTOL))
        self.max_iterations = int(opts.get("max_iterations", MAX_ITERATIONS))
        self.sensitivity_refine = bool(opts.get("sensitivity_refine", True))
        self.chord_ratio = float(opts.get("chord_ratio", CHORD_RATIO))
        if not 0.0 <= self.chord_ratio < 1.0:
            raise ValueError(
                f"chord_ratio {self.chord_ratio!r}: must be in [0, 1) (0: plain Newton)"
            )
        self.backend = resolve_backend(opts.get("solver"))
        self._init_batched(
            opts.get("processes", 1),
            functools.partial(
                SvkBeam, beam, self.scenario, self.n_steps, self.nu, markers, grid,
                parameters, {**opts, "processes": 1},
            ),
        )  # fmt: skip

        points, tets = beam.points, beam.tets
        free = np.ones(len(points), dtype=bool)
        free[beam.clamped] = False
        self.n_nodes = len(points)
        self.bounds, self.volume = extent(points, tets)
        self._asm = Assembler(points, tets, free, self.nu)
        self.n_state = self._asm.n_free
        self.parameters: ParameterSpec
        self.parameters, self._regions = parameter_regions(
            parameters, points[tets].mean(axis=1), beam.lower, beam.upper, opts.get
        )
        self._parameter_kind = parameters

        weights = beam.nodal_traction_weights()
        self._load_weights = np.repeat(weights, 3)[self._asm.free_dofs]
        self._load_dir = np.tile(np.eye(3), self.n_nodes)[
            :, self._asm.free_dofs
        ]  # (3, n)
        end = np.linalg.norm(self.external_force(self.n_steps))
        self.atol = float(opts.get("atol", ATOL * end))

        f2f = self._asm.full_to_free
        self.marker_points = marker_points(int(markers), beam.lower, beam.upper)
        self.grid_counts = tuple(int(g) for g in grid)
        self.grid_points = grid_points(self.grid_counts, beam.lower, beam.upper)  # type: ignore[arg-type]
        centre = 0.5 * (beam.lower + beam.upper)
        centre[0] = beam.upper[0]
        self._obs = interpolation_matrix(self.marker_points, points, tets, f2f)
        self._grid = interpolation_matrix(self.grid_points, points, tets, f2f)
        self._tip = interpolation_matrix(centre[None, :], points, tets, f2f)
        target = 0.5 * (beam.lower + beam.upper)  # inside, 90% along the length
        target[0] = beam.lower[0] + 0.9 * (beam.upper[0] - beam.lower[0])
        self.target_points = target[None, :]
        self._target = interpolation_matrix(self.target_points, points, tets, f2f)

        self.last_residuals: list[float] = []
        self._cost = [0, 0, 0]
        freeze(self)  # shared by the copies runs get (see NewtonSolve.__copy__)
        freeze(self._asm, keep=ASSEMBLY_BUFFERS)

    # -- the ForwardModel protocol -------------------------------------------

    def reset(self) -> FloatArray:
        """Return the unloaded state: zeros, shape (n_state,)."""
        return np.zeros(self.n_state)

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """Solve load step ``k`` (1..K) with parameters ``theta``, from ``state``.

        With ``substeps = n`` the traction goes from step k-1's to step k's in
        n equal increments, each solved by Newton.

        Raises
        ------
        ModelFailure
            No convergence within ``max_iterations``, a non-finite residual, or
            an inverted element (det F <= 0) that backtracking cannot avoid.
        """
        modulus = self._modulus(theta, k)
        if not 1 <= k <= self.n_steps:
            raise ValueError(f"load step k = {k}: must be in 1..{self.n_steps}")
        if substeps < 1:
            raise ValueError(f"substeps = {substeps}: must be >= 1")
        u = np.array(state, dtype=np.float64)
        if u.shape != (self.n_state,):
            raise ValueError(f"state has shape {u.shape}, expected ({self.n_state},)")
        self._cost[0] += 1
        self._factored_key = None
        t0, t1 = (
            self.scenario.traction(k - 1, self.n_steps),
            self.scenario.traction(k, self.n_steps),
        )
        for j in range(1, substeps + 1):
            traction = t0 + (j / substeps) * (t1 - t0)
            u, _ = self._newton(modulus, self._load(traction), u, k)
        self._remember_factorization(theta, u)
        return u

    def observe(self, state: FloatArray) -> FloatArray:
        """Marker displacements, shape (3M,), ``[p0x, p0y, p0z, p1x, ...]``."""
        return self._obs @ state

    def grid(self, state: FloatArray) -> FloatArray:
        """Displacements of the shape-error grid points, shape (G, 3)."""
        return (self._grid @ state).reshape(-1, 3)

    def targets(self, state: FloatArray) -> FloatArray:
        """Displacement (1, 3) of the hidden target: the axis at 90% of the length."""
        return np.asarray(self._target @ state).reshape(1, 3)

    def tip(self, state: FloatArray) -> FloatArray:
        """Displacement of the end-face centre, shape (3,)."""
        return self._tip @ state

    def probes(self, state: FloatArray) -> dict[str, float]:
        """Named outputs for the traces: the tip displacement ``tip_x..z`` (m)."""
        tip = self.tip(state)
        return {"tip_x": tip[0], "tip_y": tip[1], "tip_z": tip[2]}

    def sensitivity(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """D observe / d theta at the converged ``state``, shape (3M, p).

        du/dE_r = -K^-1 g_r(u), g_r the internal force of region r at unit
        modulus. Reuses the last Newton factorization when ``state`` and
        ``theta`` are those of the step just solved (plus one step of iterative
        refinement with K(u), option ``sensitivity_refine``, default on: the
        factorization is of the iterate before the solution, off by O(|last
        update|)) if that step ended with a Newton update, else factors K(u)
        once (after chord updates the factorization held is older).
        """
        modulus = self._modulus(theta, k)
        u = np.asarray(state, dtype=np.float64)
        kin_unit = self._asm.kinematics(u, np.ones(self._asm.n_elements))
        g = self._asm.region_forces(kin_unit, self._regions, self.parameters.p)
        du = self._state_sensitivity(theta, k, u, modulus, g, self.sensitivity_refine)
        return np.asarray(self._obs @ du.reshape(self.n_state, -1))

    def cost(self) -> Cost:
        """Cumulative forward solves, Newton iterations and linear solves."""
        return Cost(*self._cost)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable description of everything the results depend on."""
        s = self.scenario
        return {
            "model": "svk-beam",
            "code_version": MODEL_VERSION,
            "mesh": self.beam.spec,
            "n_nodes": self.n_nodes,
            "n_elements": len(self.beam.tets),
            "mesh_sha256": self.beam.digest(),
            "nu": self.nu,
            "parameters": self._parameter_kind,
            "parameter_names": list(self.parameters.names),
            "options": {
                k: v
                for k, v in sorted(self.options.items())
                if k not in ("solver", "processes")
            },
            "markers": len(self.marker_points),
            "grid": list(self.grid_counts),
            "scenario": {"name": s.name, "direction": list(s.direction),
                         "magnitude": s.magnitude},
            "n_steps": self.n_steps,
            "rtol": self.rtol,
            "atol": self.atol,
            "max_iterations": self.max_iterations,
        }  # fmt: skip

    # -- extras: mesh output, residual and tangent for tests -------------------

    def mesh(self) -> tuple[FloatArray, NDArray[np.int64]]:
        """Node coordinates (N, 3) and tets (T, 4)."""
        return self.beam.points, self.beam.tets

    def displacement_field(self, state: FloatArray) -> FloatArray:
        """Displacement of every node (N, 3), zeros on the clamped ones."""
        full = np.zeros(3 * self.n_nodes)
        full[self._asm.free_dofs] = state
        return full.reshape(-1, 3)

    def external_force(self, k: int) -> FloatArray:
        """Nodal external force on the free dofs at load step ``k``, (n_state,)."""
        return self._load(self.scenario.traction(k, self.n_steps))

    def internal_force(self, theta: FloatArray, state: FloatArray) -> FloatArray:
        """Assemble the internal force f_int(state; theta), shape (n_state,)."""
        modulus = self._modulus(theta, None)
        return self._asm.forces(self._asm.kinematics(np.asarray(state, float), modulus))

    def residual(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """Newton residual f_int(state; theta) - f_ext(k), shape (n_state,)."""
        return self.internal_force(theta, state) - self.external_force(k)

    def tangent(self, theta: FloatArray, state: FloatArray) -> Any:
        """Assemble the full free-free tangent at ``state`` (scipy CSR)."""
        modulus = self._modulus(theta, None)
        kin = self._asm.kinematics(np.asarray(state, float), modulus)
        return self._pattern.matrix(self._asm.tangent_data(kin, modulus, self._pattern))

    # -- internals -------------------------------------------------------------

    def _modulus(self, theta: FloatArray, k: int | None) -> FloatArray:
        th = self._theta(theta, k)
        return th[self._regions]

    def _load(self, traction: FloatArray) -> FloatArray:
        return self._load_weights * (np.asarray(traction) @ self._load_dir)


def make_model(spec: ModelSpec) -> SvkBeam:
    """Build the model described by ``spec`` (registered as ``"svk-beam"``).

    ``spec.settings`` is a :class:`BeamSettings`, a mapping of its fields, or
    None (the defaults).
    """
    settings = spec.settings
    if settings is None:
        settings = BeamSettings()
    elif isinstance(settings, Mapping):
        settings = BeamSettings(**settings)
    model = SvkBeam(
        meshes.parse(spec.mesh),
        spec.scenario,
        n_steps=spec.n_steps,
        nu=settings.nu,
        markers=spec.markers,
        grid=settings.grid,
        parameters=settings.parameters,
        options=settings.options(),
    )
    model.parameters = replace(
        model.parameters, default=settings.true_values(model.parameters.p)
    )
    return model
