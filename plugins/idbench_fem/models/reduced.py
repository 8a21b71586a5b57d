r"""The ``solid`` model on a reduced fine mesh: Galerkin POD with ECSW, online.

:class:`ReducedModel` is the forward model a ``rom:`` mesh spec builds
(:mod:`idbench_fem.models.reduction` is the offline half). Its state is the
reduced coordinates q (r,), the fine displacements being u = V q; each load
step solves the Galerkin system in q,

.. math::

    \hat r(q) = \sum_\rho \theta_\rho \hat g_\rho(q) - \tfrac{k}{K} V^T f_{ext}
    = 0,

with the hyper-reduced forces and tangents of :mod:`idbench_fem.fem.hyper`,
converged when :math:`\|\hat r\| \le \max(\mathrm{rtol} \|V^T
f_{ext}(k)\|, \mathrm{atol})` (:data:`RTOL`). The iteration is quasi-Newton:
the per-region tangents K-hat_rho (r x r) are held between solves and
combined for each theta exactly, their inverse improved by Broyden's update
within a solve, and evaluated anew only when an iteration stalls or they are
:data:`LAG` steps old; a solve starts from the previous solve's increment
(a secant predictor) where that lowers the residual. A force evaluation is
O(r T_s), a tangent O(12 r^2 T_s).
Observations, shape-error points and targets are the fine model's linear
maps times V, computed once, so a step's cost depends on r and on the
sampled elements, not on the fine mesh. The sensitivity is one reduced
solve, dq/dtheta_rho = -K-hat^-1 g-hat_rho. Everything else (the surface for
clouds, the reaction, the displacement field) is the fine model's at V q.

**Its own error.** Every :attr:`ReducedModel.error_every`-th step (and the
last), the first state solved at that step is lifted and the fine model's
residual r there is recorded: one fine force assembly, no solve. Relative to
the load, |r| / |f_ext(k)| (``reduction_residual``), it is 1e2 times the
displacement error (local imbalances the modes cannot hold); one Jacobi step
on it, max |D^-1 r| / max |u| (``reduction_error_estimate``, D the fine
tangent's diagonal at rest), is an indicator of the displacement error
itself, not a bound: within a factor of about 3 of the measured error on the
liver, 10-40 times below it on the beam (stiff slender modes, which one
Jacobi step underrates).
:meth:`ReducedModel.diagnostics` reports the largest of each as columns of
the run's row, and :meth:`ReducedModel.diagnostic_warning` flags a run
whose estimate exceeds :attr:`ReducedModel.error_tolerance`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from idbench import ConfigError, Cost, ModelFailure, ModelSpec
from idbench_fem.bodies.catalog import get_mesh, mesh_file
from idbench_fem.bodies.description import Body
from idbench_fem.fem.hyper import HyperReduced
from idbench_fem.fem.newton import checked_state, checked_theta
from idbench_fem.models.observables import LinearReadouts
from idbench_fem.models.reduction import (
    PREFIX,
    Reduction,
    ReductionSpec,
    element_dofs,
    element_factors,
    element_set,
    parse_spec,
    reduce,
    reduced_springs,
)
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid_settings import SolidSettings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

RTOL = 1e-6
"""The reduced Newton tolerance, relative to |V^T f_ext(k)| (the solid
setting ``rtol`` overrides it): the reduction's own error is 1e-3 to 1e-2 of
the displacements, so the fine model's 1e-8 would buy nothing."""

ERROR_EVERY = 5
"""Steps between two measurements of the fine residual at the lifted state."""

STALL = 0.95
"""An iteration that cut the reduced residual less than this drops the
Broyden updates of the inverse, or, if it had none, evaluates the tangents
anew. Otherwise the held ones serve, their inverse improved by Broyden's
update within a solve (one force evaluation and an r x r product an
iteration; the tangent costs about 12 r times more). Tangents are held
per region, so they serve every theta exactly (K-hat = sum theta_rho
K-hat_rho)."""

LAG = 8
"""Held tangents serve the steps up to this many after the one they were
evaluated at (not earlier steps); :meth:`ReducedModel.reset` drops them, so a
path's numbers depend on its own calls only (equal to Newton's to the
tolerance)."""

ERROR_TOLERANCE = 0.02
"""A run is flagged where its error estimate (:meth:`ReducedModel.fine_residual`:
one Jacobi step of the fine residual at V q, as a share of the largest
displacement) exceeds this."""

BACKTRACKS = 8


class ReducedModel(LinearReadouts):
    """A reduced model of ``fine``'s mesh (see the module).

    Parameters
    ----------
    fine
        The full model of the same body, manipulation, steps and markers on
        the fine mesh (the reduction's).
    reduction
        Basis, sampled elements and weights.
    spec
        The parsed ``rom:`` spec (it names the model in ``describe``).
    """

    def __init__(
        self, fine: SolidModel, reduction: Reduction, spec: ReductionSpec
    ) -> None:
        V = reduction.basis
        if V.shape[0] != fine.n_state:
            raise ValueError(
                f"reduction basis has {V.shape[0]} rows, the mesh {fine.n_state} dofs"
            )
        if fine.driven_nodes.size:
            raise ModelFailure(
                f"manipulation {fine.manipulation.name!r}: a reduced model covers "
                "force-controlled manipulations (a displacement-controlled grasp "
                "is not one)"
            )
        self.fine, self.reduction, self.spec = fine, reduction, spec
        self.parameters = fine.parameters
        self.n_steps = fine.n_steps
        self.n_state = reduction.modes
        self.rtol = float(fine.settings.rtol or RTOL)
        self.atol = float(fine.atol)
        self.max_iterations = fine.max_iterations
        self.error_every = ERROR_EVERY
        self.error_tolerance = ERROR_TOLERANCE
        self._V = V
        self._f_end = V.T @ fine.external_force(fine.n_steps)
        self._f_end_norm = float(np.linalg.norm(fine.external_force(fine.n_steps)))
        # the readouts of the reduced state q: the fine model's of V q
        self._obs = np.column_stack([fine.observe(v) for v in V.T])
        self._grid = np.column_stack([np.ravel(fine.grid(v)) for v in V.T])
        self._targets = np.column_stack([np.ravel(fine.targets(v)) for v in V.T])
        _, tets = fine.mesh()
        sample = reduction.elements
        self._hyper = HyperReduced(
            element_set(fine, tets[sample]), element_dofs(fine, tets[sample]), V,
            reduction.weights, element_factors(fine)[sample],
            fine.element_regions[sample], fine.parameters.p,
            springs=reduced_springs(fine, V),
        )  # fmt: skip
        self.marker_points = fine.marker_points
        self.target_points = fine.target_points
        self.max_markers = fine.max_markers
        self.inputs = fine.inputs  # a load's reaction: the input, not data
        self.grid_points = fine.grid_points
        self.n_nodes = fine.n_nodes
        self.bounds, self.volume = fine.bounds, fine.volume
        self._cost = [0, 0, 0]
        self.factorizations = 0
        """Tangent evaluations (and their factorizations), a count."""
        self._errors: dict[int, tuple[float, float]] = {}
        self._tangents: dict[str, Any] = {}
        """The held per-region tangents ("K"), the step they were evaluated at
        ("k"), their inverses by theta, and the last solve ("last": its step,
        start and end, for the next one's secant predictor)."""
        self._diagonals = self._jacobi()
        for a in (self._V, self._f_end, self._obs, self._grid, self._targets,
                  self._diagonals):  # fmt: skip
            a.flags.writeable = False

    def __copy__(self) -> ReducedModel:
        """A copy for one run: its own counters and error record."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        new._cost = list(self._cost)
        new._errors = {}
        new._tangents = {}
        return new

    @property
    def reduces(self) -> str:
        """The mesh spec of the fine mesh this model reduces."""
        return self.spec.mesh

    # -- the ForwardModel protocol --------------------------------------------

    def reset(self) -> FloatArray:
        """The unloaded state: q = 0 (r,); a new path (the held tangents dropped)."""
        self._tangents = {}
        return np.zeros(self.n_state)

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """Solve load step ``k`` (1..K) in q from ``state``.

        Raises
        ------
        ModelFailure
            No convergence, or an inverted sampled element in every backtrack.
        """
        th = self._theta(theta, k)
        q = checked_state(state, k, substeps, self.n_steps, self.n_state)
        self._cost[0] += 1
        start = q
        guess = None
        last = self._tangents.get("last")  # (k, start, end) of the last solve
        if substeps == 1 and last is not None and last[0] in (k, k - 1):
            guess = q + (last[2] - last[1])  # a secant predictor
        for j in range(1, substeps + 1):
            t = (k - 1 + j / substeps) / self.n_steps
            q = self._newton(th, t, q, k, guess)
        self._tangents["last"] = (k, start, q)
        if (k % self.error_every == 0 or k == self.n_steps) and k not in self._errors:
            self._errors[k] = self.fine_residual(th, k, q)
        return q

    def sensitivity(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """D observe / d theta (3M, p): H V dq, K-hat dq = -g-hat (a reduced solve)."""
        th = self._theta(theta, k)
        st = self._hyper.evaluate(np.asarray(state, dtype=float))
        dq = -self._solve(self._hyper.tangent(st, th), st.g, k)
        self._cost[2] += th.size
        return np.asarray(self._obs @ dq)

    def cost(self) -> Cost:
        """Cumulative forward solves, Newton iterations and (reduced) solves."""
        return Cost(*self._cost)

    def describe(self) -> dict[str, Any]:
        """The fine model's description and the reduction's (its key, size)."""
        out = dict(self.fine.describe())
        red = self.reduction
        out["reduction"] = {
            "key": red.key, "modes": red.modes, "elements": len(red.elements),
            "spec": f"{PREFIX}{self.spec.mesh}", "error_every": self.error_every,
        }  # fmt: skip
        return out

    # -- what else the fine model shows, at V q -------------------------------

    def load_figures(self) -> dict[str, float]:
        """The fine model's load figures (the reduction projects its loads)."""
        return self.fine.load_figures()

    def lift(self, state: FloatArray) -> FloatArray:
        """The fine model's state V q (n,)."""
        return np.asarray(self._V @ state)

    def probes(self, state: FloatArray) -> dict[str, float]:
        """The fine model's probes at V q."""
        return self.fine.probes(self.lift(state))

    def mesh(self) -> tuple[FloatArray, IntArray]:
        """The fine mesh's nodes (N, 3) and tets (T, 4)."""
        return self.fine.mesh()

    def cell_data(self) -> dict[str, FloatArray]:
        """The fine model's cell data and each tet's ECSW weight (0: not sampled)."""
        out = dict(self.fine.cell_data())
        w = np.zeros(len(self.fine.mesh()[1]))
        w[self.reduction.elements] = self.reduction.weights
        out["ecsw_weight"] = w
        return out

    def displacement_field(self, state: FloatArray) -> FloatArray:
        """Displacement of every fine node (N, 3) at V q."""
        return self.fine.displacement_field(self.lift(state))

    def surface(self, state: FloatArray) -> tuple[FloatArray, IntArray]:
        """The fine mesh's deformed boundary at V q."""
        return self.fine.surface(self.lift(state))

    def reaction(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """The fine model's reaction force at V q (a fine force assembly)."""
        return self.fine.reaction(theta, k, self.lift(state))

    # -- its own error ---------------------------------------------------------

    def fine_residual(
        self, theta: FloatArray, k: int, state: FloatArray
    ) -> tuple[float, float]:
        """The fine model's residual at V q: relative to the load, and as an error.

        ``(|r| / |f_ext(k)|, max_i |D_i^-1 r_i| / max_i |u_i|)`` with r =
        f_int(V q; theta) - f_ext(k), u = V q, i the nodes and D the diagonal
        of the fine tangent at rest at theta (one Jacobi step: an estimate of
        the displacement error as a share of the largest displacement,
        comparable to the reduction error the study measures). Both inf
        where V q inverts a fine element.
        """
        u = self.lift(state)
        r = self.fine.residual(theta, k, u)
        scale = (k / self.n_steps) * self._f_end_norm
        raw = float(np.linalg.norm(r) / max(scale, 1e-300))
        D = np.asarray(theta, float) @ self._diagonals[:-1] + self._diagonals[-1]
        step = np.linalg.norm((r / D).reshape(-1, 3), axis=1).max()
        size = np.linalg.norm(u.reshape(-1, 3), axis=1).max()
        estimate = float(step / max(size, 1e-300))
        if not (np.isfinite(raw) and np.isfinite(estimate)):
            return float("inf"), float("inf")  # V q inverts a fine element
        return raw, estimate

    def _jacobi(self) -> FloatArray:
        """The fine tangent's diagonal at rest (p + 1, n).

        One row per parameter at unit value, then the part no parameter
        scales (the known springs').
        """
        fine, p = self.fine, self.parameters.p
        th = np.asarray(fine.parameters.default, dtype=float)
        zero = np.zeros(fine.n_state)
        base = fine.tangent(th, zero).diagonal()
        out = np.zeros((p + 1, fine.n_state))
        if p == 1 and fine.springs is None:
            out[0] = base / th[0]
        else:  # K is linear in theta: one more assembly per parameter
            for rho in range(p):
                more = th.copy()
                more[rho] *= 2.0
                out[rho] = (fine.tangent(more, zero).diagonal() - base) / th[rho]
            out[p] = base - th @ out[:p]
        return out

    def diagnostics(self) -> dict[str, float]:
        """The largest fine residual and error estimate measured this run.

        ``reduction_residual`` (|r| / |f_ext|) and ``reduction_error_estimate``
        (see :meth:`fine_residual`).
        """
        if not self._errors:
            return {}
        raw, estimate = np.max(np.array(list(self._errors.values())), axis=0)
        return {"reduction_residual": float(raw),
                "reduction_error_estimate": float(estimate)}

    def diagnostic_warning(self) -> str:
        """Why the run's reduction is not to be trusted ("" if it is)."""
        if not self._errors:
            return ""
        k, (_, worst) = max(self._errors.items(), key=lambda kv: kv[1][1])
        if worst <= self.error_tolerance:
            return ""
        return (
            f"the reduced model's error estimate reached {worst:.3g} of the peak "
            f"displacement at step {k} (tolerance {self.error_tolerance:g}): its "
            "states are outside what its design's snapshots cover"
        )

    # -- internals -------------------------------------------------------------

    def _theta(self, theta: FloatArray, k: int | None) -> FloatArray:
        return checked_theta(theta, self.parameters.p, k)

    def _held_inverse(self, th: FloatArray, k: int) -> FloatArray:
        """K-hat^-1 (r, r) of the held tangents at ``th`` (computed once per theta)."""
        key = th.tobytes()
        inverse = self._tangents.get(key)
        if inverse is None:
            K = self._hyper.combine(self._tangents["K"], th)
            inverse = self._solve(K, np.eye(len(K)), k)
            self._tangents[key] = inverse
        return np.asarray(inverse)

    def _solve(self, K: FloatArray, rhs: FloatArray, k: int) -> FloatArray:
        """K^-1 rhs by Cholesky (LU where K is not positive definite)."""
        try:
            return np.asarray(scipy.linalg.cho_solve(scipy.linalg.cho_factor(K), rhs))
        except (np.linalg.LinAlgError, ValueError):
            try:
                return np.asarray(scipy.linalg.solve(K, rhs))
            except (np.linalg.LinAlgError, ValueError) as exc:
                raise ModelFailure(f"singular reduced tangent: {exc}", step=k) from exc

    def _newton(
        self, th: FloatArray, t: float, q: FloatArray, k: int,
        guess: FloatArray | None = None,
    ) -> FloatArray:  # fmt: skip
        """Quasi-Newton in q for the load fraction ``t`` of the end load.

        From ``q``, or from ``guess`` where its residual is smaller; with the
        held tangents' inverse, improved by Broyden's update after each
        iteration (see :data:`STALL` and :data:`LAG`).
        """
        hyper = self._hyper
        f_ext = t * self._f_end
        tol = max(self.rtol * float(np.linalg.norm(f_ext)), self.atol)
        st = hyper.evaluate(q)
        if not st.valid:
            raise ModelFailure("the starting state inverts a sampled element", step=k)
        r = hyper.force(st, th) - f_ext
        if guess is not None:
            at = hyper.evaluate(guess)
            r_at = hyper.force(at, th) - f_ext if at.valid else r
            if at.valid and np.linalg.norm(r_at) < np.linalg.norm(r):
                q, st, r = guess, at, r_at
        res: list[float] = []
        H = None
        updated = False  # whether H carries Broyden updates
        r_old = dq = np.zeros(0)
        for it in range(self.max_iterations + 1):
            if it > 0:
                r = hyper.force(st, th) - f_ext
            norm = float(np.linalg.norm(r))
            res.append(norm)
            if not np.isfinite(norm):
                raise ModelFailure(f"non-finite reduced residual (iteration {it})", k)
            if norm <= tol:
                self._cost[1] += it
                return q
            if it == self.max_iterations or norm > 1e10 * max(res[0], tol):
                self._cost[1] += it
                raise ModelFailure(
                    f"reduced Newton did not converge in {it} iterations: |r| = "
                    f"{norm:.3e} > tol {tol:.3e}", step=k,
                )  # fmt: skip
            stalled = it > 0 and norm > STALL * res[-2]
            if stalled and updated:  # first back to the held tangents' inverse
                H, updated = None, False
            elif stalled or not 0 <= k - self._tangents.get("k", -LAG - 1) <= LAG:
                last = self._tangents.get("last")
                self._tangents = {"K": hyper.region_tangents(st), "k": k, "last": last}
                self.factorizations += 1
                H = None
            if H is None:
                H = self._held_inverse(th, k).copy()
            elif it > 0:  # Broyden's ("good") update of the inverse
                updated = True
                y = r - r_old
                Hy = H @ y
                denom = float(dq @ Hy)
                if abs(denom) > 1e-300:
                    H += np.outer(dq - Hy, dq @ H) / denom
            dq = -(H @ r)
            self._cost[2] += 1
            for _ in range(BACKTRACKS + 1):
                st = hyper.evaluate(q + dq)
                if st.valid:
                    break
                dq = 0.5 * dq
            else:
                self._cost[1] += it + 1
                raise ModelFailure("inverted sampled element in every backtrack", k)
            q = q + dq
            r_old = r
        raise AssertionError("unreachable")  # pragma: no cover


def reduced_model(
    body: Body, manipulation: str, spec: ModelSpec, settings: SolidSettings
) -> ReducedModel:
    """The reduced model a ``rom:`` mesh spec asks for (see :data:`~.reduction.SYNTAX`).

    Builds (or reads from the cache) the reduction of the body's design, and
    the full model of the manipulation on the fine mesh it reduces.

    Raises
    ------
    ConfigError
        The body has what the reduction does not carry yet: a shape imaged
        under load (``[reference]``) or a modulus field (``[field]``).
    """
    held = [
        what
        for what, present in (
            ("a [reference] imaged shape", body.reference is not None),
            ("a [field]", body.modulus_field is not None),
        )
        if present
    ]
    if held:
        raise ConfigError(
            f"mesh {spec.mesh!r}: a reduced model does not carry "
            f"{' or '.join(held)} of {body.source}; use a full mesh "
            "(--meshes without rom:)"
        )
    rspec = parse_spec(spec.mesh)
    settings = replace(settings, processes=None)
    reduction = reduce(body, rspec, settings, design_check)
    fine = SolidModel(
        body, get_mesh(mesh_file(body, rspec.mesh)), manipulation,
        get_mesh(mesh_file(body, settings.reference or "truth")), spec.n_steps,
        spec.markers, settings,
    )  # fmt: skip
    return ReducedModel(fine, reduction, rspec)


def design_check(
    reduction: Reduction, models: list[SolidModel], paths: list[FloatArray]
) -> dict[str, float]:
    """The reduction on its own design paths, where the fine states are known.

    Every :data:`ERROR_EVERY`-th step of each path (at its moduli) the
    reduced model's fine residual, its error estimate and its error (largest
    nodal displacement error over the path's peak) are measured:
    ``design_residual``, ``design_error_estimate`` and ``design_error`` are
    the largest; ``design_failures`` counts the paths the reduced model
    could not follow to their end.
    """
    assert models and paths
    body = models[0].body
    thetas = body.design.thetas() if body.design is not None else None
    assert thetas is not None
    spec = ReductionSpec("design")
    worst_r = worst_e = worst_x = 0.0
    failures = 0
    pairs = [(m, th) for m in models for th in thetas]
    for (model, theta), states in zip(pairs, paths, strict=True):
        rom = ReducedModel(model, reduction, spec)
        peak = float(np.linalg.norm(states.reshape(len(states), -1, 3), axis=2).max())
        q = rom.reset()
        for k in range(1, len(states) + 1):
            try:
                q = rom.step(theta, k, q)
            except ModelFailure:
                failures += 1
                break
            if k % ERROR_EVERY == 0 or k == len(states):
                residual, estimate = rom.fine_residual(theta, k, q)
                if np.isfinite(residual):  # (inf: V q inverts a fine tet)
                    worst_r = max(worst_r, residual)
                    worst_x = max(worst_x, estimate)
                d = (rom.lift(q) - states[k - 1]).reshape(-1, 3)
                worst_e = max(worst_e, float(np.linalg.norm(d, axis=1).max()) / peak)
    return {"design_residual": worst_r, "design_error": worst_e,
            "design_error_estimate": worst_x, "design_failures": float(failures)}
