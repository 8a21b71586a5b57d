r"""Batched load steps of the beam and solid models: sigma points share factors.

For St Venant-Kirchhoff, neo-Hookean at fixed nu (any energy linear in the
moduli) the internal force and tangent of region-wise moduli theta are

.. math::

    f_{int}(u; \theta) = \sum_r \theta_r g_r(u), \qquad
    K(u; \theta) = \sum_r \theta_r K_r(u),

so near a state u_f where K(u_f; theta_f) is factored, K(u; theta) is about
s K(u_f; theta_f) with the scalar s = prod_r (theta_r / theta_{f,r})^{w_r}
(w_r region r's share of the volume weighted by its elements' moduli at
unit parameters, :func:`_region_weights`; exact for one region at u = u_f).
:func:`step_many` advances r parameter/state pairs to load step k:

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
   that is theta_i - theta_a to the first order (:func:`_prediction_steps`):
   linear in theta for one parameter, in 1 / theta for several (the slabs'
   compliances add), or from its given state if that inverts an element, or
   if the prediction's residual exceeds ``FAR`` |f_ext| and the given state's
   is smaller (far from the anchor, a prediction can be worse than no move);
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
(:data:`CHORD_LIMITS`: more chords where residuals are compiled), the tangent
is refactored at the current iterate (a full Newton step);
that factorization then serves the later pairs and the next call.

Where the model reuses factorizations along a path (setting ``path_reuse``
not false: the organs), the pairs' chords are Anderson-accelerated
(:func:`_accelerated_chords`, :data:`ANDERSON`): each iterate combines the
last ones, which on a linear residual is GMRES preconditioned by the held
factorization, so the few modes that factorization misses (a region softer
than at the factorization) no longer set the rate; an iteration that raises
|r|, or ``ANDERSON["most"]`` without convergence, refactor at the iterate.
The beam (plain Newton) keeps the chords above.

Each result therefore meets the convergence test of ``step`` on the same
load: it equals ``step(theta_i, k, state_i)`` to the Newton tolerance, not
bitwise (a different iterate satisfies the same test). Backtracking keeps
det F > 0 as in ``step``. Failures raise :class:`idbench.ModelFailure`, and
the caller may fall back to ``step`` (with its sub-step retries).
"""

from __future__ import annotations

import functools
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from idbench import ModelFailure
from idbench_fem.fem import step_workers
from idbench_fem.fem.newton import NewtonSolve, backtrack
from idbench_fem.fem.step_workers import Helper, HelperLost

if TYPE_CHECKING:
    from idbench_fem.fem.svk_assembly import Kinematics

FloatArray = NDArray[np.float64]

CHORD_LIMITS = {False: (0.1, 6), True: (0.5, 15)}
"""(SLOW, MAX_MODIFIED) by whether the assembler's residuals are compiled.

A chord iteration is refactored away when it reduces |r| by less than a
factor SLOW, or after MAX_MODIFIED in a row. It costs a residual and a
back-substitution: with numpy kernels about a quarter of a Newton iteration
at 500 nodes (kernel and factorization), and a rate slower than 0.1 does not
pay; with the compiled kernel (:mod:`idbench_fem.fem.kernels`) about a
fifteenth, and chords pay down to 0.5. Measured on the RO-UKF path with p = 4
(benchmarks/filters.py, one process): numpy 3.38 forward steps a step with
(0.1, 6), 4.14 with (0.5, 15); compiled 2.62 with (0.1, 6) and 6.3
factorizations a step, 2.1-2.3 with (0.4-0.6, 15-30) and 3.2-3.4.
"""


BETA = 2.0
"""The form of the predictions with several parameters (:func:`_prediction_steps`):
linear in 1 / theta, as the tip deflection of slabs in series (their
compliances add). On the RO-UKF path with 4 slabs (benchmarks/filters.py):
6.3 factorizations a step, against 6.7 in log theta and 7.25 linear in theta."""

BETA_ONE = 0.0
"""The form with one parameter: linear in theta. A large deflection stiffens
the beam, so 1 / E overshoots far from the anchor (the RO-UKF's first step
from rest: residual 9e9 x tol against 3e8; 2.1 factorizations a step against
1.55 over the path); near it the forms agree to 1%."""

FAR = 10.0
"""A prediction whose residual exceeds FAR |f_ext| is compared with the given state."""

BATCH_ELEMENTS = 50_000
"""Elements (rows x tets) per vectorised residual evaluation of predictions."""

POLYNOMIAL_ABOVE = 8
"""With one parameter and more predictions than this, their residuals come
from the cubic through four assemblies (:func:`_line_residuals`)."""


@dataclass
class BatchStats:
    """Work of the batched steps, cumulative (for benchmarks and tests).

    Attributes
    ----------
    calls, pairs
        Calls of :func:`step_many` and parameter/state pairs advanced.
    modified
        Modified-Newton iterations (residual + back-substitution, no factor).
    converged_at_prediction
        Pairs whose prediction from the anchor already met the tolerance.
    """

    calls: int = 0
    pairs: int = 0
    modified: int = 0
    converged_at_prediction: int = 0


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


@dataclass
class _PathStep:
    """What :meth:`BatchedSteps._path_step` leaves for the next call.

    Attributes
    ----------
    k, path
        Its load step and the states of the path so far, latest first: its
        solution, its start and, if that call also continued one, the
        previous start (up to :data:`PATH_ORDER` + 1 states).
    theta_f, factorizations
        The parameters of the factorization the solver holds and the model's
        count of factorizations then (reused only if nothing refactored since).
    record, chords
        Its chord iterations (:func:`_modified_newton`'s record) and how many
        chords the next step makes before it refactors (None: no limit): the
        chords kept before one raised |r| (:func:`_useful_chords`), or the
        limit it had itself if it still had to refactor.
    """

    k: int
    path: tuple[FloatArray, ...]
    theta_f: FloatArray
    factorizations: int
    record: list[str] = field(default_factory=list)
    chords: int | None = None


PATH_ORDER = 2
"""Degree of the polynomial through the last states that predicts a step's
start along a path (:meth:`BatchedSteps._path_step`; 2: quadratic, as the
anchor's extrapolated increment in :func:`step_many`). On the liver's
grasp-lift (1,000 nodes, 20 steps) the residual at the prediction is 2.4x
below that at the previous state with a secant (degree 1), 45x with degree 2."""

_EXTRAPOLATION = {1: (2.0, -1.0), 2: (3.0, -3.0, 1.0)}


class BatchedSteps(NewtonSolve):
    """Mixin: :meth:`step_many` for a Newton model whose force is linear in theta.

    The model provides, besides :class:`~idbench_fem.fem.newton.NewtonSolve`'s
    needs, ``n_state``, ``n_steps``, ``_regions`` (each element's parameter,
    (T,)), ``external_force(k)``, ``_modulus(theta, k)`` (the elements'
    moduli, linear in theta), ``step`` and ``force_is_cubic`` (True where the
    internal force is a cubic polynomial of the state, as for SVK: then
    :func:`_line_residuals` serves many predictions with one parameter); its
    assembler says in ``STACKS`` whether it evaluates a stack of states at
    once. Its ``__init__`` calls :meth:`_init_batched`.
    """

    n_state: int
    n_steps: int
    _regions: NDArray[np.int64]
    force_is_cubic: bool = False
    processes: int = 1
    _recipe: Callable[[], Any] | None = None
    _batch_anchor: _PreviousCall | None = None
    _batch_stats: BatchStats | None = None
    RUN_CACHES = (
        *NewtonSolve.RUN_CACHES,
        "_batch_anchor",
        "_batch_stats",
        "_last_path_step",
    )
    _last_path_step: _PathStep | None = None

    def external_force(self, k: int) -> FloatArray:  # pragma: no cover
        """External force on the free dofs at load step ``k``, (n_state,)."""
        raise NotImplementedError

    def _modulus(  # pragma: no cover
        self, theta: FloatArray, k: int | None
    ) -> FloatArray:
        raise NotImplementedError

    def _path_reference(
        self, k: int, u: FloatArray, modulus: FloatArray, f_ext: FloatArray
    ) -> float:
        """|r| at ``u`` (converged at step k - 1) for step k: the load increment.

        A model that prescribes displacements (no load increment) evaluates it.
        """
        return float(np.linalg.norm(f_ext - self.external_force(k - 1)))

    def _prescribe(self, k: int, fraction: float = 1.0) -> None:
        """Set any prescribed displacements to step k's (none here)."""

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

    @functools.cached_property
    def _unit_modulus(self) -> FloatArray:
        """The elements' moduli at theta = 1, (T,).

        f_int(u; theta) = sum_r theta_r g_r(u), g_r evaluated at these moduli.
        """
        return self._modulus(np.ones(self.parameters.p), None)

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
        return step_many(self, thetas, k, states)

    def _path_step(
        self, theta: FloatArray, k: int, state: FloatArray, modulus: FloatArray
    ) -> FloatArray:
        """One load step along a path, reusing the last step's factorization.

        The rule (:data:`CHORD_LIMITS` for when to refactor): when this call
        continues the previous one on this model (step k after k - 1, from
        the state that call returned, bitwise) and the solver still holds the
        factorization that call left (no factorization since), the step
        starts from the extrapolation of the path's last states (quadratic,
        :data:`PATH_ORDER`, or a secant after one step; from ``state`` if the
        prediction inverts an element or has a residual above the load
        increment, which is the residual at ``state``; evaluated there when
        the model prescribes displacements, :meth:`_path_reference`) and iterates
        chords with that factorization (refactoring after as many chords as
        paid on the step before, if one there raised |r|), scaled to
        ``theta`` as in :func:`step_many`; a chord that cuts |r| by less than
        SLOW, or MAX_MODIFIED chords in a row, refactor at the iterate.
        Otherwise it is the model's plain Newton from ``state``. Either way
        the result meets the same residual test, so it equals a fresh solve
        to the Newton tolerance (not bitwise), and the same calls on a fresh
        model give the same numbers (the cache is this instance's and keyed
        on its own last call).
        """
        u = np.array(state, dtype=np.float64)
        f_ext = self.external_force(k)
        prev = self._last_path_step
        self._last_path_step = None
        out = None
        record: list[str] = []
        continues = (
            prev is not None and prev.k == k - 1 and np.array_equal(prev.path[0], u)
        )
        reuse = prev is not None and prev.factorizations == self.factorizations
        if continues and reuse and prev is not None:
            asm = self._asm
            tol = max(self.rtol * float(np.linalg.norm(f_ext)), self.atol)
            coef = _EXTRAPOLATION[min(PATH_ORDER, len(prev.path) - 1)]
            guess = np.sum([c * x for c, x in zip(coef, prev.path, strict=False)], 0)
            kin = asm.kinematics(guess, modulus)
            res = asm.forces(kin) - f_ext
            # the residual at ``state`` (converged at step k - 1) is the load
            # increment to the tolerance: evaluated only if the guess is worse
            step_load = self._path_reference(k, u, modulus, f_ext)
            if np.all(kin.det > 0) and np.linalg.norm(res) < step_load:
                u = guess
            else:
                kin = asm.kinematics(u, modulus)
                res = asm.forces(kin) - f_ext
            if np.all(kin.det > 0):
                self.last_residuals = [float(np.linalg.norm(res))]
                out, theta_f = _modified_newton(
                    self, theta, modulus, f_ext, u, kin, res, tol, k,
                    prev.theta_f, _region_weights(self), prev.chords, record,
                )  # fmt: skip
                self.last_update_factored = False
        if out is None:
            out, _ = self._newton(modulus, f_ext, np.array(state, dtype=np.float64), k)
            theta_f = theta
        assert theta_f is not None
        path: tuple[FloatArray, ...] = (out.copy(), np.array(state, dtype=np.float64))
        if continues and prev is not None:
            path += prev.path[1:PATH_ORDER]
        chords = _useful_chords(record)
        if chords is None and continues and prev is not None and "F" in record:
            chords = prev.chords  # the limit held and a refactorization was due
        self._last_path_step = _PathStep(
            k, path, np.array(theta_f, dtype=np.float64), self.factorizations,
            record, chords,
        )  # fmt: skip
        return out

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

    @property
    def batch_stats(self) -> BatchStats:
        """Factorizations and iterations of :meth:`step_many` so far."""
        if self._batch_stats is None:
            self._batch_stats = BatchStats()
        return self._batch_stats


def _useful_chords(record: list[str]) -> int | None:
    """Chords that paid on the previous path step before one raised |r|.

    From a :func:`_modified_newton` record: when its chords with the
    factorization it was given ran into a discarded one (``"x"``) before any
    refactorization, the number kept before it (the next step refactors
    after as many, saving the wasted chord); else None (no limit).
    """
    n = 0
    for event in record:
        if event == "c":
            n += 1
        elif event == "x":
            return n
        else:
            return None
    return None


def _central(log_thetas: FloatArray) -> int:
    """Index of the row nearest (L1) to the median of the rows, the first if tied."""
    d = np.abs(log_thetas - np.median(log_thetas, axis=0)).sum(axis=1)
    return int(np.argmin(d))


def step_many(
    model: BatchedSteps, thetas: FloatArray, k: int, states: FloatArray
) -> FloatArray:
    """Advance r parameter/state pairs to load step ``k``; see the module docstring.

    Parameters
    ----------
    model
        The model (its caches, solver and cost counters are used and updated).
    thetas
        Parameters, shape (r, p).
    k
        Load step, 1..K.
    states
        Starting states, shape (r, n); not modified.

    Returns
    -------
    numpy.ndarray
        Converged states (r, n), row i equal to ``model.step(thetas[i], k,
        states[i])`` to the Newton tolerance.
    """
    th = np.asarray(thetas, dtype=np.float64)
    X = np.asarray(states, dtype=np.float64)
    p, n = model.parameters.p, model._asm.n_free  # the unknowns
    if th.ndim != 2 or th.shape[1] != p:
        raise ValueError(f"thetas has shape {th.shape}, expected (r, {p})")
    if X.shape != (len(th), n):
        raise ValueError(f"states has shape {X.shape}, expected ({len(th)}, {n})")
    if not 1 <= k <= model.n_steps:
        raise ValueError(f"load step k = {k}: must be in 1..{model.n_steps}")
    moduli = [model._modulus(t, k) for t in th]  # validates every theta
    r = len(th)
    out = np.empty((r, n))
    if r == 0:
        return out
    stats = model.batch_stats
    stats.calls += 1
    stats.pairs += r
    settled_before = stats.converged_at_prediction
    model._cost[0] += r
    model._factored_key = None
    asm = model._asm
    f_ext = model.external_force(k)
    tol = max(model.rtol * float(np.linalg.norm(f_ext)), model.atol)
    log_th = np.log(th)
    weights = _region_weights(model)

    # 1. the anchor: when the previous call was at step k - 1, from the
    # extrapolated increment by chord iterations with the factorization that
    # call left (if nothing refactored since), else by the model's Newton.
    # Nothing is reused across a restart of the path (k not following), so a
    # run's results do not depend on the runs before it on the same model.
    a = _central(log_th)
    prev = model._batch_anchor
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
            helpers = model._step_helpers()
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
    if prev is not None and prev.factorizations == model.factorizations:
        kin = asm.kinematics(start, moduli[a]) if kin is None else kin
        if np.all(kin.det > 0):
            res = asm.forces(kin) - f_ext
            u_a, theta_f = _solve_pair(
                model, th[a], moduli[a], f_ext, start, kin, res, tol, k,
                prev.theta_f, weights,
            )  # fmt: skip
    if u_a is None:
        f0 = model.factorizations
        u_a, _ = model._newton(moduli[a], f_ext, np.array(start), k)
        if r > 1 and model.factorizations == f0:  # converged at once: factor for S
            model._factor(asm.kinematics(u_a, moduli[a]), moduli[a], k)
        theta_f = th[a]
    out[a] = u_a

    # 2. sensitivity du/dtheta at the anchor (one solve per parameter) with
    # the factorization in hand: only a predictor, so it need not be exact
    S = None
    if r > 1:
        kin_unit = asm.kinematics(u_a, model._unit_modulus)
        g = asm.region_forces(kin_unit, model._regions, p)
        scale = float(np.exp(weights @ np.log(th[a] / theta_f)))
        S = -model._solver.solve(g).reshape(n, p) / scale
        model._cost[2] += p

    # 3. the others: predictions, their residuals in batches (most sigma
    # points of a full UKF already meet the tolerance there), then chords,
    # shared with the helper processes (option ``processes``) if any
    if len(others):
        assert S is not None
        steps = _prediction_steps(th[a], th[others], BETA_ONE if p == 1 else BETA)
        preds = u_a + steps @ S.T
        if p == 1 and len(others) > POLYNOMIAL_ABOVE and model.force_is_cubic:
            ok, norms, residuals = _line_residuals(
                model, u_a, S[:, 0], steps[:, 0], th[others, 0], f_ext
            )
        else:
            mods = np.stack([moduli[i] for i in others])
            ok, norms, residuals = _residuals(model, preds, mods, f_ext)
        done = ok & (norms <= tol)
        stats.converged_at_prediction += int(done.sum())
        out[others[done]] = preds[done]
        todo = np.flatnonzero(~done)
        rows = PendingPairs(th[others], preds, X[others], residuals, ok)
        helpers = model._step_helpers() if len(todo) > 1 and not early else []
        # contiguous shares, the larger ones to the helpers (this process
        # has solved the anchor); fixed by the order, not by timing
        shares = np.array_split(todo, min(len(todo), len(helpers) + 1) or 1)
        sent = []
        for helper, share in zip(helpers, shares[:-1], strict=False):
            helper.submit(k, rows.take(share))
            sent.append((helper, share))
        out[others[shares[-1]]], theta_f = solve_rows(
            model, k, rows.take(shares[-1]), theta_f
        )
        for helper, share in sent:
            out[others[share]], theta_f = _collect(
                model, k, helper, rows.take(share), theta_f
            )
    # the helpers' answers (after an exception here they are left pending,
    # and a helper's next submit discards them)
    for helper, share in early:
        rows = PendingPairs(th[share], X[share] + incr, X[share])
        out[share], theta_f = _collect(model, k, helper, rows, theta_f)
    assert theta_f is not None
    model._batch_anchor = _PreviousCall(
        k,
        X[a].copy(),
        u_a.copy(),
        theta_f.copy(),
        model.factorizations,
        None if prev is None else prev.final - prev.start,
        r > 1 and stats.converged_at_prediction == settled_before,
    )
    return out


def _prediction_steps(
    theta_a: FloatArray, thetas: FloatArray, beta: float
) -> FloatArray:
    """Steps t (r, p) of the predictions u_a + S t from the anchor's theta_a.

    u is predicted linearly in theta^(1 - beta) (in log theta for beta = 1),
    scaled to the first order of theta: t = theta_a ((theta /
    theta_a)^(1 - beta) - 1) / (1 - beta). Beta = 0 is linear in theta, 2
    linear in 1 / theta (exact for a linear model with one modulus, where u is
    proportional to 1 / E, and for regions in series, whose compliances add).
    """
    if beta == 0.0:
        return np.asarray(thetas - theta_a)
    ratio = thetas / theta_a
    if beta == 1.0:
        return np.asarray(theta_a * np.log(ratio))
    return np.asarray(theta_a * (ratio ** (1.0 - beta) - 1.0) / (1.0 - beta))


@dataclass
class PendingPairs:
    """Pairs still to converge: what :func:`solve_rows` (and a helper) needs.

    Attributes
    ----------
    thetas, preds, starts
        Parameters (r, p), predicted states (r, n) and the given states
        (r, n), where a row starts if its prediction inverts an element.
    residuals, ok
        The predictions' residuals (r, n) and whether they invert no element
        (r,), if known (else :func:`solve_rows` evaluates them).
    """

    thetas: FloatArray
    preds: FloatArray
    starts: FloatArray
    residuals: FloatArray | None = None
    ok: NDArray[np.bool_] | None = None

    def take(self, index: NDArray[np.intp]) -> PendingPairs:
        """The rows ``index``."""
        known = self.residuals is not None and self.ok is not None
        return PendingPairs(
            self.thetas[index], self.preds[index], self.starts[index],
            self.residuals[index] if known else None,  # type: ignore[index]
            self.ok[index] if known else None,  # type: ignore[index]
        )  # fmt: skip


def solve_rows(
    model: BatchedSteps, k: int, rows: PendingPairs, theta_f: FloatArray | None
) -> tuple[FloatArray, FloatArray | None]:
    """Converge each row by chord iterations from its prediction (or its start).

    Returns the states and the theta of the factorization then held
    (``theta_f`` None: none yet, the first row factors).
    """
    asm = model._asm
    f_ext = model.external_force(k)
    tol = max(model.rtol * float(np.linalg.norm(f_ext)), model.atol)
    weights = _region_weights(model)
    out = np.empty_like(rows.preds)
    for j, theta in enumerate(rows.thetas):
        modulus = model._modulus(theta, k)
        kin = None
        if rows.ok is None or rows.residuals is None:
            kin = asm.kinematics(rows.preds[j], modulus)
            ok, res = bool(np.all(kin.det > 0)), asm.forces(kin) - f_ext
        else:
            ok, res = bool(rows.ok[j]), rows.residuals[j]
        u = rows.preds[j]
        if ok and np.linalg.norm(res) <= tol:
            model.batch_stats.converged_at_prediction += 1
        elif not ok or np.linalg.norm(res) > FAR * np.linalg.norm(f_ext):
            # a prediction worse than no displacement at all (parameters far
            # from the anchor's): start from the given state if that is better
            kin0 = asm.kinematics(rows.starts[j], modulus)
            res0 = asm.forces(kin0) - f_ext
            if not ok or np.linalg.norm(res0) < np.linalg.norm(res):
                u, kin, res = rows.starts[j], kin0, res0
        out[j], theta_f = _solve_pair(
            model, theta, modulus, f_ext, u, kin, res, tol, k, theta_f, weights
        )
    return out, theta_f


Work = tuple[list[int], int, int, int]
"""A helper's work: cost counter increments, factorizations, chord iterations,
pairs converged at their prediction."""


def helper_solve(
    model: BatchedSteps, k: int, rows: PendingPairs
) -> tuple[FloatArray, Work]:
    """:func:`solve_rows` in a helper process, from no factorization.

    Returns the states and the work done, which the caller adds to its model's
    counters (:func:`_add_work`).
    """
    model._prescribe(k)
    stats = model.batch_stats
    cost, fac = list(model._cost), model.factorizations
    mod, settled = stats.modified, stats.converged_at_prediction
    states, _ = solve_rows(model, k, rows, None)
    work = (
        [a - b for a, b in zip(model._cost, cost, strict=True)],
        model.factorizations - fac,
        stats.modified - mod,
        stats.converged_at_prediction - settled,
    )
    return states, work


def _collect(
    model: BatchedSteps,
    k: int,
    helper: Helper,
    rows: PendingPairs,
    theta_f: FloatArray | None,
) -> tuple[FloatArray, FloatArray | None]:
    """A helper's states for ``rows`` (solved here if the helper is lost)."""
    try:
        states, work = helper.collect()
    except HelperLost:  # solved here instead, as without helpers
        return solve_rows(model, k, rows, theta_f)
    _add_work(model, work)
    return states, theta_f


def _add_work(model: BatchedSteps, work: Work) -> None:
    """Count a helper's work as the model's own."""
    cost, fac, mod, settled = work
    for i, c in enumerate(cost):
        model._cost[i] += c
    model.factorizations += fac
    model.batch_stats.modified += mod
    model.batch_stats.converged_at_prediction += settled


def _region_weights(model: BatchedSteps) -> FloatArray:
    """Stiffness fraction of each parameter region, (p,).

    A region's volume weighted by its elements' moduli at unit parameters
    (its volume fraction where those are all 1).
    """
    w = np.bincount(
        model._regions,
        weights=model._asm.volumes * model._unit_modulus,
        minlength=model.parameters.p,
    )
    return np.asarray(w / w.sum())


def _residuals(
    model: BatchedSteps, states: FloatArray, moduli: FloatArray, f_ext: FloatArray
) -> tuple[NDArray[np.bool_], FloatArray, FloatArray]:
    """Residuals f_int - f_ext of each row (r, n), their norms (r,), det F > 0 (r,).

    Vectorised over rows in chunks of about ``BATCH_ELEMENTS`` elements (one
    row at a time if the assembler's ``STACKS`` is false); rows with an
    inverted element get an infinite norm.
    """
    asm = model._asm
    r = len(states)
    ok = np.zeros(r, dtype=bool)
    norms = np.full(r, np.inf)
    residuals = np.empty_like(states)
    stacks = asm.STACKS
    step = max(1, BATCH_ELEMENTS // asm.n_elements) if stacks else 1
    for lo in range(0, r, step):
        if stacks:
            kin = asm.kinematics(states[lo : lo + step], moduli[lo : lo + step])
            good = np.all(kin.det > 0, axis=1)
            res = asm.forces(kin) - f_ext
        else:  # an assembler of one state at a time
            kin = asm.kinematics(states[lo], moduli[lo])
            good = np.array([np.all(kin.det > 0)])
            res = (asm.forces(kin) - f_ext)[None, :]
        ok[lo : lo + step] = good
        norms[lo : lo + step] = np.where(good, np.linalg.norm(res, axis=1), np.inf)
        residuals[lo : lo + step] = res
    return ok, norms, residuals


def _line_residuals(
    model: BatchedSteps,
    u_a: FloatArray,
    s: FloatArray,
    t: FloatArray,
    thetas: FloatArray,
    f_ext: FloatArray,
) -> tuple[NDArray[np.bool_], FloatArray, FloatArray]:
    """:func:`_residuals` of the predictions u_a + t_j s at theta_j, for p = 1.

    The SVK internal force at unit parameters is a cubic polynomial of the
    displacement (P = F S, S linear in the Green strain, which is quadratic),
    so along the line u_a + t s it is g(t) = c0 + c1 t + c2 t^2 + c3 t^3
    exactly, and so is det F of each element. Four assemblies at Chebyshev
    points of the range of t give the coefficients; every prediction's
    residual theta_j g(t_j) - f_ext is then a polynomial evaluation, O(n)
    instead of an assembly over the elements (the full UKF has 2n + 1
    predictions a step). Round-off: about 1e-12 |f_ext| even for parameters
    30% apart (tests/test_skfem_batched.py), far below the tolerance (1e-8
    |f_ext|).
    """
    asm = model._asm
    r = len(t)
    h = float(np.max(np.abs(t), initial=0.0))
    if h == 0.0:  # every prediction is u_a itself
        kin = asm.kinematics(u_a, model._unit_modulus)
        g, good = asm.forces(kin), bool(np.all(kin.det > 0))
        residuals = thetas[:, None] * g - f_ext
        ok = np.full(r, good)
        return ok, np.where(ok, np.linalg.norm(residuals, axis=1), np.inf), residuals
    nodes = h * np.cos(np.pi * (np.arange(4) + 0.5) / 4)  # Chebyshev, in [-h, h]
    unit = model._unit_modulus
    forces, dets = [], []
    for x in nodes:
        kin = asm.kinematics(u_a + x * s, unit)
        forces.append(asm.forces(kin))
        dets.append(kin.det)
    vander = np.vander(nodes / h, 4, increasing=True)  # scaled: well conditioned
    coef_f = np.linalg.solve(vander, np.array(forces))  # (4, n)
    coef_d = np.linalg.solve(vander, np.array(dets))  # (4, T)
    powers = np.vander(t / h, 4, increasing=True)  # (r, 4)
    residuals = thetas[:, None] * (powers @ coef_f) - f_ext
    ok = np.empty(r, dtype=bool)
    step = max(1, BATCH_ELEMENTS // asm.n_elements)
    for lo in range(0, r, step):
        ok[lo : lo + step] = np.all(powers[lo : lo + step] @ coef_d > 0, axis=1)
    norms = np.where(ok, np.linalg.norm(residuals, axis=1), np.inf)
    return ok, norms, residuals


def _modified_newton(
    model: BatchedSteps,
    theta: FloatArray,
    modulus: FloatArray,
    f_ext: FloatArray,
    u: FloatArray,
    kin: Kinematics | None,
    res: FloatArray,
    tol: float,
    k: int,
    theta_f: FloatArray | None,
    weights: FloatArray,
    first_chords: int | None = None,
    record: list[str] | None = None,
) -> tuple[FloatArray, FloatArray | None]:
    """Chord iterations with the factored tangent, refactoring when they are slow.

    ``kin`` and ``res`` are the kinematics (None: computed when needed) and the
    residual at the start ``u``; ``theta_f`` is the theta of the factorization
    held (None: none, the first iteration factors). Returns the converged state
    and the theta of the factorization now held. ``first_chords``: refactor
    after that many chords with the given factorization, before any test
    says so (0: at once). ``record`` gets "c" for each chord kept, "x" for
    one discarded (it raised |r|) and "F" for each factorization.
    """
    asm = model._asm
    stats = model.batch_stats
    slow, most = CHORD_LIMITS[asm.compiled]
    norm = float(np.linalg.norm(res))
    if norm <= tol:
        return u, theta_f
    first = norm
    refactor = theta_f is None or first_chords == 0
    modified = full = in_row = 0
    log = [] if record is None else record
    while True:
        if refactor:
            if kin is None:
                kin = asm.kinematics(u, modulus)
            model._factor(kin, modulus, k)
            log.append("F")
            theta_f = theta
            scale = 1.0
            full += 1
            in_row = 0
        else:
            assert theta_f is not None  # refactor starts True without one
            in_row += 1
            scale = float(np.exp(weights @ np.log(theta / theta_f)))
            modified += 1
        du = model._solver.solve(-res) / scale
        model._cost[1] += 1
        model._cost[2] += 1
        u_new, kin_new, res_new, norm_new = _updated(asm, u, du, modulus, f_ext, k)
        if norm_new <= tol:
            stats.modified += modified
            return u_new, theta_f
        if full >= model.max_iterations:
            stats.modified += modified
            raise ModelFailure(
                f"batched Newton did not converge ({full} full, {modified} modified "
                f"iterations): |r| = {norm_new:.3e} > tol {tol:.3e} "
                f"(first |r| = {first:.3e})",
                step=k,
            )
        if norm_new > norm and not refactor:
            log.append("x")
            refactor = True  # the chord step made it worse: discard it, refactor
            continue
        if not refactor:
            log.append("c")
        refactor = norm_new > slow * norm or in_row >= most
        if first_chords is not None and full == 0 and in_row >= first_chords:
            refactor = True
        u, kin, res, norm = u_new, kin_new, res_new, norm_new


ANDERSON = {"depth": 12, "most": 16}
"""The accelerated chords of the sigma points (:func:`_accelerated_chords`):
``depth``, the past iterations whose differences the Anderson step combines;
``most``, the iterations with one factorization before the tangent is
refactored at the iterate. Measured on the RO-UKF path (benchmarks/organs.py,
one process; the work a step, factorizations, back-substitutions and
residuals, at their unit costs measured alone at load 0.4): kidney p = 2 at
2,000 nodes 48 ms a step (0.4 factorizations, 32 solves) against 79 with the
chords of :func:`_modified_newton` (2.3, 25); most 12: 52, 25: 59; depth 4:
54-62. Liver p = 4 slabs at 1,000 nodes 45 (3.55 factorizations, 45 solves)
against 42 (4.05, 32); most 25: 41 (0.9, 70), 12: 44. A nodal regional
scaling of the preconditioner instead of the scalar s raised the residual
at the first iteration (kidney 81 ms)."""


ACCELERATE_FROM_DOFS = 4000
"""Free dofs from which :func:`step_many` accelerates the chords of p > 1.

A proxy, deterministic, for a factorization costing many back-substitutions:
the kidney at 2,004 nodes (5,800 free dofs) gains (79 -> 48 ms a step), the
liver with 4 slabs at 975 nodes (2,800) does not (42 -> 45: a factorization
there costs only about 20 back-substitutions). See :data:`ANDERSON`."""


def _updated(
    asm: Any,
    u: FloatArray,
    du: FloatArray,
    modulus: FloatArray,
    f_ext: FloatArray,
    k: int,
) -> tuple[FloatArray, Kinematics, FloatArray, float]:
    """The backtracked update of a pair and its residual: u, kinematics, r, |r|.

    Raises
    ------
    ModelFailure
        As :func:`~idbench_fem.fem.newton.backtrack`, or for a non-finite residual.
    """
    u_new, kin_new = backtrack(asm, u, du, modulus, k)
    res_new = asm.forces(kin_new) - f_ext
    norm_new = float(np.linalg.norm(res_new))
    if not np.isfinite(norm_new):
        raise ModelFailure("non-finite residual in a batched step", step=k)
    return u_new, kin_new, res_new, norm_new


def _accelerates(model: BatchedSteps, p: int) -> bool:
    """Whether :func:`step_many` accelerates its chords (:func:`_accelerated_chords`).

    For p > 1 parameters on a model that reuses factorizations along a path
    (its setting ``path_reuse`` is not false) with at least
    :data:`ACCELERATE_FROM_DOFS` free dofs. The beam's plain Newton keeps the
    chords of :func:`_modified_newton` (the default comparison's numbers,
    bitwise), and so do p = 1 and small meshes, where they cost less.
    """
    settings = getattr(model, "settings", None)
    if getattr(settings, "path_reuse", False) is False or p < 2:
        return False
    return int(model._asm.n_free) >= ACCELERATE_FROM_DOFS


def _solve_pair(
    model: BatchedSteps,
    theta: FloatArray,
    modulus: FloatArray,
    f_ext: FloatArray,
    u: FloatArray,
    kin: Kinematics | None,
    res: FloatArray,
    tol: float,
    k: int,
    theta_f: FloatArray | None,
    weights: FloatArray,
) -> tuple[FloatArray, FloatArray | None]:
    """Converge one pair of :func:`step_many` (accelerated chords or plain ones)."""
    solve = _accelerated_chords if _accelerates(model, len(theta)) else _modified_newton
    return solve(model, theta, modulus, f_ext, u, kin, res, tol, k, theta_f, weights)


def _accelerated_chords(
    model: BatchedSteps,
    theta: FloatArray,
    modulus: FloatArray,
    f_ext: FloatArray,
    u: FloatArray,
    kin: Kinematics | None,
    res: FloatArray,
    tol: float,
    k: int,
    theta_f: FloatArray | None,
    weights: FloatArray,
) -> tuple[FloatArray, FloatArray | None]:
    """Chord iterations with the held factorization, Anderson-accelerated.

    The chord map u -> u + f(u), f(u) = -K_f^-1 r(u) / s (K_f the held
    factorization, s its scale to theta as in :func:`_modified_newton`), is
    a fixed-point iteration whose rate is that of the modes K_f misses (a
    region softer or stiffer than at the factorization, a soft mode of the
    grasp): the chords creep. Anderson's step combines the last
    ``ANDERSON["depth"]`` iterates: with F_j = f(u_j), dF and dU the
    differences of successive F and u, gamma = argmin |F_j - dF gamma| and
    u_{j+1} = u_j + F_j - (dU + dF) gamma, which on a linear residual is
    GMRES preconditioned by K_f (a Krylov acceleration at the cost of a
    chord: one residual and one back-substitution, no tangent). An
    iteration that raises |r| is discarded, and it and
    ``ANDERSON["most"]`` iterations without convergence refactor the
    tangent at the (best) iterate and restart the history; that
    factorization serves the later pairs and the next call. With no
    factorization held this is :func:`_modified_newton` (which factors
    first). Same convergence test, backtracking (det F > 0) and failures as
    :func:`_modified_newton`; returns the state and the theta of the
    factorization now held.
    """
    if theta_f is None:
        return _modified_newton(
            model, theta, modulus, f_ext, u, kin, res, tol, k, theta_f, weights
        )
    asm = model._asm
    solver = model._solver
    norm = first = float(np.linalg.norm(res))
    if norm <= tol:
        return u, theta_f
    depth, most = ANDERSON["depth"], ANDERSON["most"]
    scale = float(np.exp(weights @ np.log(theta / theta_f)))
    f = -np.asarray(solver.solve(res)) / scale
    model._cost[2] += 1
    dU: list[FloatArray] = []
    dF: list[FloatArray] = []
    its = total = full = 0
    fresh = False  # the last iterate was a Newton step (just refactored)
    while True:
        its += 1
        total += 1
        model._cost[1] += 1
        step = f
        if dF:
            Fm = np.stack(dF, axis=1)
            step = f - (np.stack(dU, axis=1) + Fm) @ _mixing(Fm, f)
        u_new, kin_new, res_new, norm_new = _updated(asm, u, step, modulus, f_ext, k)
        if norm_new <= tol:
            model.batch_stats.modified += total - full
            return u_new, theta_f
        if full >= model.max_iterations:
            model.batch_stats.modified += total - full
            raise ModelFailure(
                f"batched Newton did not converge ({full} factorizations, {total} "
                f"accelerated chords): |r| = {norm_new:.3e} > tol {tol:.3e} "
                f"(first |r| = {first:.3e})",
                step=k,
            )
        if norm_new > norm or its >= most:
            if norm_new > norm and not fresh:  # discard the chord that raised |r|
                u_new, kin_new, res_new, norm_new = u, kin, res, norm
            if kin_new is None:
                kin_new = asm.kinematics(u_new, modulus)
            model._factor(kin_new, modulus, k)
            theta_f, scale, its = theta, 1.0, 0
            full += 1
            fresh = True
            dU.clear()
            dF.clear()
            f_new = -np.asarray(solver.solve(res_new))
        else:
            fresh = False
            f_new = -np.asarray(solver.solve(res_new)) / scale
            dU.append(u_new - u)
            dF.append(f_new - f)
            if len(dU) > depth:
                dU.pop(0)
                dF.pop(0)
        model._cost[2] += 1
        u, kin, res, norm, f = u_new, kin_new, res_new, norm_new, f_new


def _mixing(Fm: FloatArray, f: FloatArray) -> FloatArray:
    """Anderson's gamma = argmin |f - Fm gamma|, Fm (n, m) with m small.

    By the normal equations, columns scaled to unit norm and a 1e-10
    ridge (a tenth of the cost of an SVD least squares at n = 2,700, where
    that costs more than the back-substitution); least squares if singular.
    """
    scale = np.linalg.norm(Fm, axis=0)
    scale[scale == 0] = 1.0
    A = Fm / scale
    G = A.T @ A + 1e-10 * np.eye(A.shape[1])
    try:
        return np.asarray(np.linalg.solve(G, A.T @ f) / scale)
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.lstsq(A, f, rcond=None)[0] / scale)
