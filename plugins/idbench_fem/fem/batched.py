r"""Batched load steps of the beam and solid models: sigma points share factors.

For St Venant-Kirchhoff, neo-Hookean at fixed nu (any energy linear in the
moduli) the internal force and tangent of region-wise moduli theta are

.. math::

    f_{int}(u; \theta) = \sum_r \theta_r g_r(u), \qquad
    K(u; \theta) = \sum_r \theta_r K_r(u),

so near a state u_f where K(u_f; theta_f) is factored, K(u; theta) is about
s K(u_f; theta_f) with the scalar s = prod_r (theta_r / theta_{f,r})^{w_r}
(w_r region r's share of the volume weighted by its elements' moduli at
unit parameters, :func:`~idbench_fem.fem.predictions.region_weights`; exact
for one region at u = u_f). :meth:`BatchedSteps.step_many` advances r
parameter/state pairs to load step k:

1. the *anchor*, the pair whose theta is nearest the median: if the
   previous call was at step k - 1, it starts from state_a + d, d the
   increment (u - state) of the previous call's anchor, extrapolated linearly
   from the two previous increments when there are two, and is solved by
   chord iterations (below) with the factorization the previous call left,
   if nothing has refactored since; otherwise the model's own Newton
   (:meth:`~idbench_fem.fem.newton.NewtonSolve._newton`) solves it from its
   given state. Nothing carries over a restart of the load path, so a
   filter run's results do not depend on what ran before it on the same
   model;
2. the sensitivity S = du/dtheta = -K^-1 [g_1 ... g_p] at the anchor's
   solution u_a costs p back-substitutions with the factorization in hand;
3. every other pair i starts from the prediction u_a + S t_i, t_i a step
   that is theta_i - theta_a to the first order
   (:func:`~idbench_fem.fem.predictions.prediction_steps`): linear in theta
   for one parameter, in 1 / theta for several (the slabs' compliances add),
   or from its given state if that inverts an element, or if the
   prediction's residual exceeds ``FAR`` |f_ext| and the given state's is
   smaller (far from the anchor, a prediction can be worse than no move);
   the residuals of all predictions are evaluated together (vectorised over
   pairs), and only the pairs whose prediction misses the tolerance iterate.

With the model option ``processes = n > 1`` (:mod:`idbench_fem.fem.step_workers`)
the pairs that iterate are split in n contiguous shares, fixed by their
order: n - 1 helper processes solve theirs (from no factorization) while this
process solves the last share. When the previous call's predictions settled
no pair (typical of several regions: the sensitivity predicts them poorly),
the helpers' shares go out before the anchor solves, predicted as state_i + d
(the anchor's extrapolated increment), so the anchor overlaps them.

The chord (modified Newton) iteration is u <- u - K_f^-1 r(u) / s_i with the
last factorization K_f, testing the *true* residual r(u) = f_int(u; theta_i)
- f_ext against the same tolerance as the model's ``step``. When an iteration
reduces |r| by less than a factor SLOW, or after MAX_MODIFIED in a row
(:data:`~idbench_fem.fem.chords.CHORD_LIMITS`: more chords where residuals
are compiled), the tangent is refactored at the current iterate (a full Newton step);
that factorization then serves the later pairs and the next call.

Where the model reuses factorizations along a path (setting ``path_reuse``
not false: the organs), the pairs' chords are Anderson-accelerated
(:func:`~idbench_fem.fem.chords.accelerated_chords`,
:data:`~idbench_fem.fem.chords.ANDERSON`): each iterate combines the last
ones, which on a linear residual is GMRES preconditioned by the held
factorization, so the few modes that factorization misses (a region softer
than at the factorization) no longer set the rate; an iteration that raises
|r|, or ``ANDERSON["most"]`` without convergence, refactor at the iterate.
The beam (plain Newton) keeps the chords above.

Each result therefore meets the convergence test of ``step`` on the same
load: it equals ``step(theta_i, k, state_i)`` to the Newton tolerance, not
bitwise (a different iterate satisfies the same test). Backtracking keeps
det F > 0 as in ``step``. Failures raise :class:`idbench.ModelFailure`, and
the caller may fall back to ``step`` (with its sub-step retries).

The chords are in :mod:`idbench_fem.fem.chords`, the predictions in
:mod:`idbench_fem.fem.predictions`, the pairs handed to helper processes in
:mod:`idbench_fem.fem.pairs`, and the path steps that ``step`` takes (with
what the model provides) in :mod:`idbench_fem.fem.path_steps`.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench_fem.fem import chords, predictions, step_workers
from idbench_fem.fem.pairs import PendingPairs, collect, helper_solve
from idbench_fem.fem.path_steps import PathSteps
from idbench_fem.fem.predictions import BETA, BETA_ONE, FAR, POLYNOMIAL_ABOVE
from idbench_fem.fem.step_workers import Helper

FloatArray = NDArray[np.float64]

ACCELERATE_FROM_DOFS = 4000
"""Free dofs from which :meth:`BatchedSteps.step_many` accelerates the chords of p > 1.

A proxy, deterministic, for a factorization costing many back-substitutions:
the kidney at 2,004 nodes (5,800 free dofs) gains (79 -> 48 ms a step), the
liver with 4 slabs at 975 nodes (2,800) does not (42 -> 45: a factorization
there costs only about 20 back-substitutions). See
:data:`~idbench_fem.fem.chords.ANDERSON`."""


@dataclass
class _PreviousCall:
    """What the previous call leaves for the next one.

    Attributes
    ----------
    k, start, final
        Its load step and its anchor's start and solution (the increment
        predicts the next anchor's).
    theta_f, factorizations
        The parameters of the factorization the solver holds, and the model's
        count of factorizations then: the next call reuses the factorization
        only if nothing else has refactored since.
    increment
        The previous call's anchor increment, if that call was at step k - 1.
    unsettled
        Whether no other pair met the tolerance at its prediction (then the
        next call hands pairs to helper processes before the anchor solves).
    """

    k: int
    start: FloatArray
    final: FloatArray
    theta_f: FloatArray
    factorizations: int
    increment: FloatArray | None = None
    unsettled: bool = False


class BatchedSteps(PathSteps):
    """Mixin: :meth:`step_many` for a Newton model whose force is linear in theta.

    The model provides, besides :class:`~idbench_fem.fem.path_steps.PathSteps`'
    needs, ``n_state``, ``n_steps``, ``step`` and ``force_is_cubic`` (True
    where the internal force is a cubic polynomial of the state, as for SVK:
    then :func:`~idbench_fem.fem.predictions.line_residuals` serves many
    predictions with one parameter); its assembler says in ``STACKS`` whether
    it evaluates a stack of states at once. Its ``__init__`` calls
    :meth:`_init_batched`.
    """

    n_state: int
    n_steps: int
    force_is_cubic: bool = False
    processes: int = 1
    _recipe: Callable[[], Any] | None = None
    _batch_anchor: _PreviousCall | None = None
    RUN_CACHES = (*PathSteps.RUN_CACHES, "_batch_anchor")

    def _init_batched(self, processes: Any, recipe: Callable[[], Any]) -> None:
        """Check ``processes`` and keep the recipe that rebuilds the model.

        ``recipe`` is a picklable callable returning an equal model with one
        process (a helper builds its copy with it).

        Raises
        ------
        ValueError
            If ``processes`` is not a whole number >= 1.
        """
        if isinstance(processes, bool) or not isinstance(processes, int) \
                or processes < 1:  # fmt: skip
            raise ValueError(
                f"processes {processes!r}: need a whole number >= 1 "
                "(1: no helper processes)"
            )
        self.processes = processes
        self._recipe = recipe
        self._helpers: list[Helper] = []

    def step_many(self, thetas: FloatArray, k: int, states: FloatArray) -> FloatArray:
        """Solve load step ``k`` for r parameter/state pairs, sharing factorizations.

        ``thetas`` (r, p), ``states`` (r, n) -> states (r, n); row i equals
        ``step(thetas[i], k, states[i])`` to the Newton tolerance. See
        :mod:`idbench_fem.fem.batched`. In ``cost()``, each pair counts as a
        forward solve and each chord (modified Newton) iteration as a Newton
        iteration and a linear solve; ``factorizations`` counts the
        factorizations they share (with option ``processes``, the helper
        processes' too).

        Raises
        ------
        ModelFailure
            If any pair fails (the caller may retry pairs with ``step``).
        """
        th = np.asarray(thetas, dtype=np.float64)
        X = np.asarray(states, dtype=np.float64)
        p, n = self.parameters.p, self._asm.n_free  # the unknowns
        if th.ndim != 2 or th.shape[1] != p:
            raise ValueError(f"thetas has shape {th.shape}, expected (r, {p})")
        if X.shape != (len(th), n):
            raise ValueError(f"states has shape {X.shape}, expected ({len(th)}, {n})")
        if not 1 <= k <= self.n_steps:
            raise ValueError(f"load step k = {k}: must be in 1..{self.n_steps}")
        moduli = [self.element_moduli(t, k) for t in th]  # validates every theta
        r = len(th)
        out = np.empty((r, n))
        if r == 0:
            return out
        stats = self.batch_stats
        stats.calls += 1
        stats.pairs += r
        settled_before = stats.converged_at_prediction
        self.count(forward_solves=r)
        self._factored_key = None
        asm = self._asm
        f_ext = self.external_force(k)
        tol = max(self.rtol * float(np.linalg.norm(f_ext)), self.atol)
        log_th = np.log(th)
        weights = self.region_weights()

        # 1. the anchor: when the previous call was at step k - 1, from the
        # extrapolated increment by chord iterations with the factorization that
        # call left (if nothing refactored since), else by the model's Newton.
        # Nothing is reused across a restart of the path (k not following), so a
        # run's results do not depend on the runs before it on the same model.
        a = predictions.central(log_th)
        prev = self._batch_anchor
        if prev is not None and prev.k != k - 1:
            prev = None  # not the previous step of the same path: start afresh
        start = X[a]
        kin = None
        others = np.flatnonzero(np.arange(r) != a)
        early: list[tuple[Helper, NDArray[np.intp]]] = []
        if prev is not None:
            incr = prev.final - prev.start
            if prev.increment is not None:
                incr = 2.0 * incr - prev.increment
            if prev.unsettled and len(others) > 1:
                # no prediction settled a pair last step: the helpers start now
                # from the anchor's predicted increment, while the anchor solves
                helpers = self._step_helpers()
                shares = np.array_split(others, min(len(others), len(helpers) + 1))
                for helper, share in zip(helpers, shares[:-1], strict=False):
                    helper.submit(k, PendingPairs(th[share], X[share] + incr, X[share]))
                    early.append((helper, share))
                others = shares[-1]
            kin = asm.kinematics(X[a] + incr, moduli[a])
            if np.all(kin.det > 0):
                start = X[a] + incr
            else:
                kin = None
        u_a = None
        if prev is not None and prev.factorizations == self.factorizations:
            kin = asm.kinematics(start, moduli[a]) if kin is None else kin
            if np.all(kin.det > 0):
                res = asm.forces(kin) - f_ext
                u_a, theta_f = self._pair_chords(len(th[a]))(
                    self, th[a], moduli[a], f_ext, start, kin, res, tol, k,
                    prev.theta_f, weights,
                )  # fmt: skip
        if u_a is None:
            f0 = self.factorizations
            u_a, _ = self._newton(moduli[a], f_ext, np.array(start), k)
            if r > 1 and self.factorizations == f0:  # converged at once: factor for S
                self.factor(asm.kinematics(u_a, moduli[a]), moduli[a], k)
            theta_f = th[a]
        out[a] = u_a

        # 2. sensitivity du/dtheta at the anchor (one solve per parameter) with
        # the factorization in hand: only a predictor, so it need not be exact
        S = None
        if r > 1:
            kin_unit = asm.kinematics(u_a, self.unit_moduli)
            g = asm.region_forces(kin_unit, self.element_regions, p)
            scale = float(np.exp(weights @ np.log(th[a] / theta_f)))
            S = -self.solve(g).reshape(n, p) / scale
            self.count(linear_solves=p)

        # 3. the others: predictions, their residuals in batches (most sigma
        # points of a full UKF already meet the tolerance there), then chords,
        # shared with the helper processes (option ``processes``) if any
        if len(others):
            assert S is not None
            steps = predictions.prediction_steps(
                th[a], th[others], BETA_ONE if p == 1 else BETA
            )
            preds = u_a + steps @ S.T
            if p == 1 and len(others) > POLYNOMIAL_ABOVE and self.force_is_cubic:
                ok, norms, residuals = predictions.line_residuals(
                    asm, self.unit_moduli, u_a, S[:, 0], steps[:, 0],
                    th[others, 0], f_ext,
                )  # fmt: skip
            else:
                mods = np.stack([moduli[i] for i in others])
                ok, norms, residuals = predictions.residuals(asm, preds, mods, f_ext)
            done = ok & (norms <= tol)
            stats.converged_at_prediction += int(done.sum())
            out[others[done]] = preds[done]
            todo = np.flatnonzero(~done)
            rows = PendingPairs(th[others], preds, X[others], residuals, ok)
            helpers = self._step_helpers() if len(todo) > 1 and not early else []
            # contiguous shares, the larger ones to the helpers (this process
            # has solved the anchor); fixed by the order, not by timing
            shares = np.array_split(todo, min(len(todo), len(helpers) + 1) or 1)
            sent = []
            for helper, share in zip(helpers, shares[:-1], strict=False):
                helper.submit(k, rows.take(share))
                sent.append((helper, share))
            out[others[shares[-1]]], theta_f = self.solve_pairs(
                k, rows.take(shares[-1]), theta_f
            )
            for helper, share in sent:
                out[others[share]], theta_f = collect(
                    self, k, helper, rows.take(share), theta_f
                )
        # the helpers' answers (after an exception here they are left pending,
        # and a helper's next submit discards them)
        for helper, share in early:
            rows = PendingPairs(th[share], X[share] + incr, X[share])
            out[share], theta_f = collect(self, k, helper, rows, theta_f)
        assert theta_f is not None
        self._batch_anchor = _PreviousCall(
            k,
            X[a].copy(),
            u_a.copy(),
            theta_f.copy(),
            self.factorizations,
            None if prev is None else prev.final - prev.start,
            r > 1 and stats.converged_at_prediction == settled_before,
        )
        return out

    def solve_pairs(
        self, k: int, rows: PendingPairs, theta_f: FloatArray | None
    ) -> tuple[FloatArray, FloatArray | None]:
        """Converge each row by chord iterations from its prediction (or its start).

        Returns the states and the theta of the factorization then held
        (``theta_f`` None: none yet, the first row factors). What a helper
        process runs (:func:`~idbench_fem.fem.pairs.helper_solve`).
        """
        asm = self._asm
        f_ext = self.external_force(k)
        tol = max(self.rtol * float(np.linalg.norm(f_ext)), self.atol)
        weights = self.region_weights()
        out = np.empty_like(rows.preds)
        for j, theta in enumerate(rows.thetas):
            modulus = self.element_moduli(theta, k)
            kin = None
            if rows.ok is None or rows.residuals is None:
                kin = asm.kinematics(rows.preds[j], modulus)
                ok, res = bool(np.all(kin.det > 0)), asm.forces(kin) - f_ext
            else:
                ok, res = bool(rows.ok[j]), rows.residuals[j]
            u = rows.preds[j]
            if ok and np.linalg.norm(res) <= tol:
                self.batch_stats.converged_at_prediction += 1
            elif not ok or np.linalg.norm(res) > FAR * np.linalg.norm(f_ext):
                # a prediction worse than no displacement at all (parameters far
                # from the anchor's): start from the given state if that is better
                kin0 = asm.kinematics(rows.starts[j], modulus)
                res0 = asm.forces(kin0) - f_ext
                if not ok or np.linalg.norm(res0) < np.linalg.norm(res):
                    u, kin, res = rows.starts[j], kin0, res0
            out[j], theta_f = self._pair_chords(len(theta))(
                self, theta, modulus, f_ext, u, kin, res, tol, k, theta_f, weights
            )
        return out, theta_f

    def _pair_chords(
        self, p: int
    ) -> Callable[..., tuple[FloatArray, FloatArray | None]]:
        """What converges a pair of p parameters in :meth:`step_many`.

        :func:`~idbench_fem.fem.chords.accelerated_chords` where
        :func:`accelerates` says so, else the plain chords of
        :func:`~idbench_fem.fem.chords.modified_newton`.
        """
        accelerate = accelerates(self, p)
        return chords.accelerated_chords if accelerate else chords.modified_newton

    def _step_helpers(self) -> list[Helper]:
        """The live helper processes (``processes - 1``, started on first use).

        One model's helpers run at a time in a thread (see
        :func:`idbench_fem.fem.step_workers.start`); this model's start again once
        all of them were closed (by :meth:`close` or by another model's
        start). A lost helper is not replaced while others of this model live.
        A forked copy of the model starts its own (its starter's stay its
        starter's).
        """
        box = self._helpers
        if any(not h.owned for h in box):  # a forked copy of this model
            step_workers.close_all(box)  # (the copies of the sockets only)
        # a run's copy (see NewtonSolve.__copy__) uses its master's helpers
        owner = self.__dict__.get("_master", self)
        if self.processes > 1 and (not box or all(h.closed for h in box)):
            assert self._recipe is not None
            if not box:  # the first start: stop them with the model
                weakref.finalize(owner, step_workers.close_all, box)
            count = self.processes - 1
            box[:] = step_workers.start(owner, count, self._recipe, helper_solve)
            if not box:  # could not start one: do not try at every step
                self.processes = owner.processes = 1
        return [h for h in box if h.alive]

    def close(self) -> None:
        """Stop the helper processes, if any (they also stop with this process)."""
        step_workers.close_all(self._helpers)


def accelerates(model: BatchedSteps, p: int) -> bool:
    """Whether ``step_many`` accelerates its chords (Anderson's, in chords).

    For p > 1 parameters on a model that reuses factorizations along a path
    (its setting ``path_reuse`` is not false) with at least
    :data:`ACCELERATE_FROM_DOFS` free dofs. The beam's plain Newton keeps the
    chords of :func:`~idbench_fem.fem.chords.modified_newton` (the default
    comparison's numbers, bitwise), and so do p = 1 and small meshes, where
    they cost less.
    """
    settings = getattr(model, "settings", None)
    if getattr(settings, "path_reuse", False) is False or p < 2:
        return False
    return int(model.assembler.n_free) >= ACCELERATE_FROM_DOFS
